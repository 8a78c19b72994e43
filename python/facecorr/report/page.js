// facecorr report: sort (click a column), filter (text, flagged only), the larger view of a row.
(function () {
  "use strict";
  var table = document.getElementById("results");
  var tbody = table.tBodies[0];
  var heads = table.tHead.rows[0].cells;
  var rows = Array.prototype.slice.call(tbody.rows);
  var details = JSON.parse(document.getElementById("details").textContent);
  var filter = document.getElementById("filter");
  var flaggedOnly = document.getElementById("flagged-only");
  var shown = document.getElementById("shown");
  var noneShown = document.getElementById("none-shown");
  var viewer = document.getElementById("viewer");
  var viewerImg = document.getElementById("viewer-img");
  var viewerTitle = document.getElementById("viewer-title");
  var viewerInfo = document.getElementById("viewer-info");
  var viewerCaption = document.getElementById("viewer-caption");
  var sorted = { col: 2, dir: "desc" }; // the order the page is written in: worst first
  var current = null;

  function esc(s) {
    return String(s).replace(/[&<>"']/g, function (c) {
      return { "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c];
    });
  }
  function fmt(v, digits, scale, suffix) {
    return v === null || v === undefined ? "–" : (v * (scale || 1)).toFixed(digits) + (suffix || "");
  }

  function sortKey(tr, col, type) {
    var v = tr.cells[col].getAttribute("data-v");
    if (v === null || v === "") return null;
    return type === "num" ? parseFloat(v) : v.toLowerCase();
  }

  // Sort the rows by column ``col`` ("asc" or "desc"); ties and empty cells keep the worst-first order
  // (empty cells last).
  function sortBy(col, dir) {
    var type = heads[col].getAttribute("data-sort");
    var sign = dir === "asc" ? 1 : -1;
    var keyed = rows.map(function (tr) { return [sortKey(tr, col, type), +tr.getAttribute("data-i"), tr]; });
    keyed.sort(function (a, b) {
      if (a[0] === null || b[0] === null) {
        if (a[0] === b[0]) return a[1] - b[1];
        return a[0] === null ? 1 : -1;
      }
      if (a[0] < b[0]) return -sign;
      if (a[0] > b[0]) return sign;
      return a[1] - b[1];
    });
    var frag = document.createDocumentFragment();
    rows = keyed.map(function (k) { frag.appendChild(k[2]); return k[2]; });
    tbody.appendChild(frag);
    for (var i = 0; i < heads.length; i++) heads[i].classList.remove("sorted", "asc", "desc");
    heads[col].classList.add("sorted", dir);
    sorted = { col: col, dir: dir };
  }

  function applyFilter() {
    var words = filter.value.toLowerCase().split(/\s+/).filter(Boolean);
    var only = flaggedOnly.checked;
    var n = 0;
    rows.forEach(function (tr) {
      var text = tr.getAttribute("data-text");
      var ok = (!only || tr.classList.contains("flagged")) &&
        words.every(function (w) { return text.indexOf(w) >= 0; });
      tr.hidden = !ok;
      if (ok) n++;
    });
    shown.textContent = n === rows.length ? rows.length + " shown" : n + " of " + rows.length + " shown";
    noneShown.hidden = n > 0 || rows.length === 0;
  }

  function info(d) {
    var h = "<table>" +
      "<tr><td>MHD</td><td>" + fmt(d.mhd, 3, 1, " mm") + "</td></tr>" +
      "<tr><td>fit RMS</td><td>" + fmt(d.rms, 3, 1, " mm") + "</td></tr>" +
      "<tr><td>coverage</td><td>" + fmt(d.coverage, 1, 100, " %") + "</td></tr>" +
      "<tr><td>time</td><td>" + fmt(d.seconds, 1, 1, " s") + "</td></tr>" +
      "<tr><td>picture</td><td>" + (d.source === "batch" ? "written by the batch (--png)" :
        d.source === "rendered" ? "rendered by the report" : "none") +
      "</td></tr></table>";
    h += "<h4>Flags</h4>" + (d.flags.length ? "<ul>" + d.flags.map(function (f) { return "<li>" + esc(f) + "</li>"; }).join("") + "</ul>" : "<p>none</p>");
    if (d.notes.length) h += "<h4>Notes</h4><ul>" + d.notes.map(function (f) { return "<li>" + esc(f) + "</li>"; }).join("") + "</ul>";
    h += "<h4>Landmarks used <small>(" + esc(d.units) + ")</small></h4><table>";
    d.landmarks.forEach(function (l) {
      h += "<tr><td>" + esc(l[0].replace(/_/g, " ")) + "</td><td>" + fmt(l[2], 2) + "</td><td>" +
        (l[1] ? l[1].map(function (c) { return c.toFixed(1); }).join(", ") : "–") + "</td></tr>";
    });
    h += "</table><h4>Expression weights</h4>";
    h += d.expression.length ? "<table>" + d.expression.map(function (e) {
      return "<tr><td>" + esc(e[0]) + "</td><td><span class=\"wbar\" style=\"width:" + Math.round(80 * e[1]) +
        "px\"></span> " + e[1].toFixed(2) + "</td></tr>";
    }).join("") + "</table>" : "<p>all below 0.005</p>";
    return h;
  }

  function open(tr) {
    var d = details[+tr.getAttribute("data-i")];
    var img = tr.querySelector(".thumb img");
    viewerImg.hidden = !img;
    if (img) viewerImg.src = img.src;
    viewerTitle.textContent = d.name;
    viewerCaption.textContent = !img ? "no picture" : (d.source === "rendered" ?
      "left: the registered template with the landmarks used (red; the scan itself is not in the batch folder)" :
      "left: the scan with the landmarks used (red)") + " · right: the registered template coloured by its distance to the scan";
    viewerInfo.innerHTML = info(d);
    viewer.hidden = false;
    current = tr;
  }
  function close() { viewer.hidden = true; current = null; }
  function step(delta) {
    var vis = rows.filter(function (tr) { return !tr.hidden; });
    var k = vis.indexOf(current);
    if (k >= 0 && vis[k + delta]) open(vis[k + delta]);
  }

  table.tHead.addEventListener("click", function (ev) {
    var th = ev.target.closest("th");
    if (!th || !th.hasAttribute("data-sort")) return;
    var col = th.cellIndex;
    var dir = sorted.col === col ? (sorted.dir === "asc" ? "desc" : "asc") : th.getAttribute("data-first");
    sortBy(col, dir);
  });
  tbody.addEventListener("click", function (ev) {
    var tr = ev.target.closest("tr");
    if (tr) open(tr);
  });
  filter.addEventListener("input", applyFilter);
  flaggedOnly.addEventListener("change", applyFilter);
  Array.prototype.forEach.call(document.querySelectorAll("button.kind"), function (b) {
    b.addEventListener("click", function () {
      filter.value = b.getAttribute("data-filter");
      applyFilter();
      table.scrollIntoView({ block: "start" });
    });
  });
  document.getElementById("close").addEventListener("click", close);
  document.getElementById("prev").addEventListener("click", function () { step(-1); });
  document.getElementById("next").addEventListener("click", function () { step(1); });
  viewer.addEventListener("click", function (ev) { if (ev.target === viewer) close(); });
  document.addEventListener("keydown", function (ev) {
    if (viewer.hidden) return;
    if (ev.key === "Escape") close();
    else if (ev.key === "ArrowLeft") step(-1);
    else if (ev.key === "ArrowRight") step(1);
  });

  applyFilter();
  document.documentElement.setAttribute("data-ready", "1"); // for scripted checks: the page is live
})();
