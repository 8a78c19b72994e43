"""The paper's landmark pipeline (§3.2-3.6), selectable with ``start_search="paper", localise="bp"``:
Finger Print features over geodesic disks (:mod:`.features`), PCA + minimum-volume ellipsoid
classification (:mod:`.classify`, :mod:`.mvee`), the nose-first search and the flip-resolving graph
alignment (:mod:`.search`, :mod:`.alignment`), canonical forms (:mod:`.mds`) and loopy belief
propagation (:mod:`.bp`, :mod:`.localise`)."""
