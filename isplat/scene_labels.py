"""The scene's ``[labels]`` table (scene version 6; docs/labels.md, formats/scene.md):

    [labels]
    names = "totalseg.json"     # optional: a names map, JSON {"1": "spleen", ...} or CSV "id,name" rows
    opacity = 1.0               # optional: the opacity of a shown label that gives none
    show = [5, "liver"]         # optional: labels shown in the default colours
    [labels.3]                  # a label by id ...
    color = [1, 0, 0]
    opacity = 0.5
    [labels.aorta]              # ... or by name (needs names)
    color = [0.9, 0.2, 0.2]

Every problem is the kit's one line ``FILE:LINE: labels.KEY = VALUE: expected ...``. The names map is the one
file this reads (a scene's own companion, like the scene itself); whether the ids exist in the data is checked
when the augmented file is opened (:mod:`isplat.label_select`).
"""

from __future__ import annotations

import difflib

from .errors import IsplatError
from .scene_schema import LABEL_KEYS, LABELS_KEYS, TABLES_SINCE, Labels, LabelStyle
from .scene_validate import Ctx, Table

# the default colours of labels shown without one (by id, cycling): distinct, not grey
PALETTE = ((0.90, 0.25, 0.20), (0.20, 0.65, 0.30), (0.25, 0.45, 0.90), (0.95, 0.75, 0.15), (0.70, 0.30, 0.80),
           (0.10, 0.75, 0.80), (0.95, 0.50, 0.10), (0.55, 0.80, 0.20), (0.90, 0.40, 0.65), (0.50, 0.35, 0.20))
MAX_ID = 65535


def default_color(ident: int) -> tuple[float, float, float]:
    return PALETTE[(ident - 1) % len(PALETTE)]


def parse_labels(ctx: Ctx, tree: dict) -> Labels:
    """The scene's :class:`Labels` (none shown without a ``[labels]`` table)."""
    if "labels" not in tree:
        return Labels()
    raw = tree["labels"]
    if not isinstance(raw, dict):
        ctx.fail(("labels",), raw, "expected a table ([labels])")
    v = tree.get("version")
    if isinstance(v, int) and not isinstance(v, bool) and v < TABLES_SINCE["labels"]:
        ctx.fail(("labels",), "...", f"[labels] is new in scene version {TABLES_SINCE['labels']}; the file says "
                                    f"version = {v} (write version = {TABLES_SINCE['labels']}, or leave version out)")
    t = Table(ctx, {k: raw[k] for k in LABELS_KEYS if k in raw}, ("labels",),
              {"names": None, "show": [], "opacity": 1.0})
    names_path = t.read("names", ctx.path_value)
    names = _read_names(ctx, names_path) if names_path is not None else None
    opacity = t.number("opacity", "expected an opacity in [0, 1]", lo=0.0, hi=1.0)
    shown = {}
    show = t.read("show", lambda p, val: val)
    if not isinstance(show, list):
        ctx.fail(("labels", "show"), show, "expected a list of label ids or names")
    for n, item in enumerate(show):
        ident, name = _ident(ctx, ("labels", "show", n), item, names, names_path)
        shown[ident] = _placed(LabelStyle(ident, default_color(ident), opacity, name),
                               f"{ctx.where(('labels', 'show'))}: labels.show[{n}]")
    for key, sub in raw.items():
        if key in LABELS_KEYS:
            continue
        path = ("labels", key)
        if not isinstance(sub, dict):
            ctx.fail_msg(path, f"unknown key 'labels.{key}' (known keys in [labels]: {', '.join(LABELS_KEYS)}; "
                               f"a label is a table: [labels.ID] or [labels.NAME] with color and opacity)")
        ident, name = _ident(ctx, path, key, names, names_path)
        ctx.check_keys(sub, path, LABEL_KEYS, "labels.ID")
        lt = Table(ctx, sub, path, {"color": default_color(ident), "opacity": opacity})
        color = lt.vector("color", lo=0.0, hi=1.0, expected="expected 3 numbers in [0, 1] (r, g, b)")
        op = lt.number("opacity", "expected an opacity in [0, 1]", lo=0.0, hi=1.0)
        inner = path + (next(iter(sub)),) if sub else path       # (a --set names a key inside the table)
        shown[ident] = _placed(LabelStyle(ident, color, op, name), f"{ctx.where(inner)}: labels.{key}")
    return Labels(tuple(shown[i] for i in sorted(shown)), names_path, opacity)


def _placed(style: LabelStyle, where: str) -> LabelStyle:
    object.__setattr__(style, "_where", where)
    return style


def _ident(ctx: Ctx, path: tuple, key, names: dict | None, names_path) -> tuple[int, str | None]:
    """A label's id and name from its key: an id (integer or digits) or a name of the names map."""
    if isinstance(key, bool) or not isinstance(key, (int, str)):
        ctx.fail(path, key, "expected a label id (1..65535) or a name of labels.names")
    if isinstance(key, int) or key.strip().isdigit():
        ident = int(key)
        if not 1 <= ident <= MAX_ID:
            ctx.fail(path, key, f"expected a label id in 1..{MAX_ID} (0 is 'no label')")
        name = next((n for n, i in names.items() if i == ident), None) if names else None
        return ident, name
    if names is None:
        ctx.fail(path, key, "a label given by name needs labels.names (a CSV or JSON map of ids and names)")
    if key not in names:
        close = difflib.get_close_matches(key, list(names), n=1, cutoff=0.6)
        ctx.fail(path, key, f"no label of that name in {names_path.name}" +
                 (f"; did you mean {close[0]!r}?" if close else ""))
    return names[key], key


def _read_names(ctx: Ctx, path) -> dict[str, int]:
    from .labels import read_names

    try:
        return read_names(path)
    except IsplatError as exc:
        ctx.fail_msg(("labels", "names"), f"labels.names: {exc}")
