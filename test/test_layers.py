"""The layer order of docs/architecture.md, read from the code's own imports (ast).

Every import of every module under forearm_dynamics/ counts, those inside functions and
under TYPE_CHECKING too (a lazy import is still a dependency). A module may import its own
package, a peer module of its package, and any lower layer; never a higher layer, never a
package of its own layer, and no set of modules may import each other in a circle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parent.parent / "forearm_dynamics"
PKG = "forearm_dynamics"

#: Low to high. "core" is every top-level module of forearm_dynamics. Packages of one layer
#: are independent of each other. Keep in step with docs/architecture.md.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("core",),
    ("estimation",),
    ("simulation",),
    ("uncertainty",),
    ("muscles",),
    ("analysis", "viz", "bag", "codec", "formats"),
    ("offline", "muscle_validation"),
    ("nodes", "cli"),
)
RANK = {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}


def module_name(path: Path, root: Path = ROOT) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for p in sorted(root.rglob("*.py"))}


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The forearm_dynamics modules `name` imports (a package means its __init__)."""
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                up = base[:len(base) - (node.level - 1)]
                mod = ".".join(up + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            subs = [f"{mod}.{a.name}" for a in node.names if f"{mod}.{a.name}" in known]
            targets = subs if len(subs) == len(node.names) else [mod, *subs]
        for t in targets:
            while t and t not in known:  # `import forearm_dynamics.bag.reader as r`, names
                t = t.rpartition(".")[0]
            if t.startswith(PKG) and t != name:
                out.add(t)
    return out


def extensions(root: Path = ROOT) -> set[str]:
    """The C extension modules (setup.py builds each from the .c source of its name): they
    import nothing of the package."""
    return {module_name(p, root) for p in root.rglob("*.c")}


def graph(root: Path = ROOT) -> dict[str, set[str]]:
    mods = modules(root)
    known = set(mods) | extensions(root)
    return {**{m: imports_of(m, p, known) for m, p in mods.items()},
            **{m: set() for m in extensions(root)}}


def layer_of(module: str, g: dict[str, set[str]]) -> str:
    """"core" for forearm_dynamics and its top-level modules, else the package's name."""
    parts = module.split(".")
    if len(parts) == 1 or (len(parts) == 2 and not any(m.startswith(module + ".") for m in g)):
        return "core"
    return parts[1]


def upward_imports(g: dict[str, set[str]]) -> list[str]:
    bad = []
    for m, deps in sorted(g.items()):
        lm = layer_of(m, g)
        for d in sorted(deps):
            ld = layer_of(d, g)
            if ld == lm:
                continue
            if lm not in RANK or ld not in RANK:
                bad.append(f"{m} -> {d}: package {lm if lm not in RANK else ld!r} has no layer "
                           "(add it to LAYERS and docs/architecture.md)")
            elif RANK[ld] > RANK[lm]:
                bad.append(f"{m} ({lm}) imports {d} ({ld}): a higher layer")
            elif RANK[ld] == RANK[lm]:
                bad.append(f"{m} ({lm}) imports {d} ({ld}): packages of one layer are independent")
    return bad


def circles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


#: Modules that may import rclpy and the ROS message packages: the nodes, and the codec's one
#: ROS module that the offline tools (cli/, bag/, offline/) go through (docs/architecture.md).
ROS_LAYER = ("nodes",)
ROS_MODULES = (f"{PKG}.codec.ros",)
#: Top-level modules that are ROS: rclpy, its interfaces, and every message package.
ROS_ROOTS = ("rclpy", "rcl_interfaces", "builtin_interfaces", "lifecycle_msgs", "rosidl_runtime_py",
             "launch", "launch_ros")


def is_ros(module: str) -> bool:
    root = module.split(".")[0]
    return root in ROS_ROOTS or root.endswith(("_msgs", "_srvs"))


def ros_imports(root: Path = ROOT) -> list[str]:
    """Every `import rclpy` / `from std_msgs.msg import ...` outside the ROS layer."""
    bad = []
    for name, path in modules(root).items():
        parts = name.split(".")
        if name in ROS_MODULES or (len(parts) > 1 and parts[1] in ROS_LAYER):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            found = []
            if isinstance(node, ast.Import):
                found = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                found = [node.module]
            bad += [f"{name} imports {m}: go through {ROS_MODULES[0]}" for m in found if is_ros(m)]
    return sorted(bad)


def test_ros_only_in_the_ros_layer() -> None:
    """One ROS layer: only nodes/ and codec/ros.py import rclpy or a message package."""
    assert ros_imports() == []


def test_the_ros_check_sees_a_ros_import(tmp_path) -> None:
    pkg = tmp_path / PKG
    for sub in ("", "cli", "codec", "nodes"):
        (pkg / sub).mkdir(exist_ok=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "cli" / "tool.py").write_text("def f():\n    from rclpy.serialization import serialize_message\n")
    (pkg / "cli" / "other.py").write_text("import std_msgs.msg\nfrom ..codec import ros\n")
    (pkg / "codec" / "ros.py").write_text("import rclpy\n")
    (pkg / "nodes" / "node.py").write_text("import rclpy\nfrom sensor_msgs.msg import JointState\n")
    assert ros_imports(pkg) == [f"{PKG}.cli.other imports std_msgs.msg: go through {PKG}.codec.ros",
                                f"{PKG}.cli.tool imports rclpy.serialization: go through {PKG}.codec.ros"]


def test_every_package_has_a_layer() -> None:
    pkgs = {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}
    assert pkgs - set(RANK) == set(), "add the new package to LAYERS and docs/architecture.md"


def test_no_module_imports_a_higher_layer() -> None:
    assert upward_imports(graph()) == []


def test_no_import_circle() -> None:
    assert circles(graph()) == []


def test_the_checks_see_what_they_must(tmp_path) -> None:
    """The reader finds relative, absolute and lazy imports; an upward one and a circle fail."""
    pkg = tmp_path / PKG
    for sub in ("", "bag", "nodes"):
        (pkg / sub).mkdir(exist_ok=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "tree.py").write_text("def f():\n    from .nodes import node\n")
    (pkg / "bag" / "reader.py").write_text("from ..tree import x\nimport forearm_dynamics.bag.writer\n")
    (pkg / "bag" / "writer.py").write_text("from . import reader\n")
    (pkg / "nodes" / "node.py").write_text("from forearm_dynamics.bag import reader\n")
    g = graph(pkg)
    assert g[f"{PKG}.tree"] == {f"{PKG}.nodes.node"}
    assert g[f"{PKG}.bag.reader"] == {f"{PKG}.tree", f"{PKG}.bag.writer"}
    assert g[f"{PKG}.nodes.node"] == {f"{PKG}.bag.reader"}
    assert upward_imports(g) == [f"{PKG}.tree (core) imports {PKG}.nodes.node (nodes): a higher layer"]
    assert circles(g) == [[f"{PKG}.bag.reader", f"{PKG}.bag.writer", f"{PKG}.nodes.node", f"{PKG}.tree"]]
