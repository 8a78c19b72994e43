"""The layer rule of facecorr/__init__.py: every import (function-level too) points down a floor or
stays inside its own package; the two stages never import each other; nothing imports the CLI."""

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "python" / "facecorr"

#: floor of each top-level part of the package (facecorr/__init__.py's table)
FLOORS = {
    "errors": 0, "names": 0, "options": 0, "threads": 0, "chi2": 0, "_core": 0,
    "geometry": 1,
    "io": 2,
    "template": 3, "synth": 3, "render": 3,
    "landmarks": 4, "registration": 4,
    "pipeline": 5,
    "evaluation": 6, "model": 6, "report": 6,
    "cli": 7,
}
#: the package's façade and the alias table of moved paths sit above the floors
FACADE = {"facecorr/__init__.py", "facecorr/_aliases.py"}


def _module_name(path: Path) -> tuple[str, bool]:
    parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
    is_pkg = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_pkg else parts), is_pkg


def _imported(module: str, is_pkg: bool, source: str):
    """(line, absolute module imported) for every facecorr import in ``source``."""
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                stem = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            if stem == "facecorr":  # `from .. import _core` names a part of the package
                for a in node.names:
                    yield node.lineno, f"facecorr.{a.name}"
            else:
                yield node.lineno, stem


def _part(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "facecorr" and len(parts) > 1 else None


def violations(module: str, is_pkg: bool, source: str) -> list[str]:
    """Imports of ``source`` (the text of ``module``) that break the layer rule."""
    own = _part(module)
    out = []
    for line, target in _imported(module, is_pkg, source):
        other = _part(target)
        if other is None or other == own:
            continue
        if other not in FLOORS:
            out.append(f"{module}:{line} imports {target}, a part with no floor")
        elif FLOORS[other] >= FLOORS[own]:
            kind = "sideways" if FLOORS[other] == FLOORS[own] else "upwards"
            out.append(f"{module}:{line} imports {target} ({kind}: floor {FLOORS[own]} -> {FLOORS[other]})")
    return out


def test_every_part_has_a_floor():
    parts = {p.stem if p.is_file() else p.name for p in PKG.iterdir()
             if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists())) and p.name != "__init__.py"}
    parts.add("_core")
    assert parts - {"_aliases"} == set(FLOORS), parts ^ set(FLOORS)


def test_no_import_points_up_or_sideways():
    bad = []
    for path in sorted(PKG.rglob("*.py")):
        if str(path.relative_to(PKG.parent)) in FACADE:
            continue
        module, is_pkg = _module_name(path)
        bad += violations(module, is_pkg, path.read_text())
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("module, source", [
    ("facecorr.landmarks.pose", "from ..registration.alignment import kabsch"),          # stage -> stage
    ("facecorr.registration.register", "def f():\n    from ..evaluation import mhd\n"),  # upwards, in a function
    ("facecorr.geometry.mesh", "import facecorr.cli"),                                    # anything -> the CLI
    ("facecorr.template.build", "from ..render import draw_mesh"),                        # sideways on floor 3
])
def test_the_checker_catches_a_wrong_arrow(module, source):
    assert violations(module, False, source)


def test_the_checker_allows_downward_and_internal_imports():
    src = "from ..geometry.mesh import Mesh\nfrom .. import _core\nfrom .paper.bp import max_product\n"
    assert violations("facecorr.landmarks.predict", False, src) == []
