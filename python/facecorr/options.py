"""How every stage takes its settings: a frozen dataclass of defaults, changed by field name.

Each stage has one such class (``PredictOptions``, ``ExpressionOptions``, ``ShapeFitOptions``,
``RegisterOptions``, ``CorrespondOptions``) holding its defaults, the one source of truth.
"""

from __future__ import annotations

from dataclasses import replace


def resolve(options, cls, overrides: dict, caller: str):
    """``options`` (or ``cls()`` when None) with the fields in ``overrides`` changed.

    Raises TypeError naming ``caller`` and the field for an unknown field name.
    """
    opts = options if options is not None else cls()
    if not isinstance(opts, cls):
        raise TypeError(f"{caller}: options must be a {cls.__name__}, got {type(opts).__name__}")
    if not overrides:
        return opts
    try:
        return replace(opts, **overrides)
    except TypeError as e:
        raise TypeError(f"{caller}: {e}") from None
