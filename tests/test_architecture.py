"""The wiring: the package's folders are layers that import only downwards, protocols come
from the registry, modules import without cycles, and the analyse job fits the configured
model once."""

from __future__ import annotations

import ast
import inspect
import types
import typing
from pathlib import Path

import pytest

from gyrocal.io.errors import ConfigError
from gyrocal.protocols import registry

PACKAGE = Path(__file__).resolve().parents[1] / "gyrocal"


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _run_time_nodes(tree: ast.AST):
    """Every node of ``tree`` but those under ``if TYPE_CHECKING:``: an import made for the
    type checker alone runs never, so it makes no cycle."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            yield from (n for child in node.orelse for n in [child, *_run_time_nodes(child)])
            continue
        yield node
        yield from _run_time_nodes(node)


def _imports(name: str, path: Path, modules: dict, *, run_time: bool = False) -> set[str]:
    """Every gyrocal module ``name`` imports, at module level or inside a function; with
    ``run_time``, not those for the type checker alone."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    tree = ast.parse(path.read_text())
    for node in _run_time_nodes(tree) if run_time else ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            targets = [
                f"{module}.{a.name}" if f"{module}.{a.name}" in modules else module for a in node.names
            ]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            continue
        for target in targets:
            while target not in modules and "." in target:
                target = target.rsplit(".", 1)[0]
            # a package's own modules importing it (for its __init__) is not a cycle
            if target in modules and target != name and not name.startswith(target + "."):
                found.add(target)
    return found


def test_no_import_cycle_in_the_package():
    modules = _modules()
    graph = {m: _imports(m, p, modules, run_time=True) for m, p in modules.items()}
    done, path = set(), []

    def visit(m):
        if m in path:
            raise AssertionError("import cycle: " + " -> ".join(path[path.index(m) :] + [m]))
        if m in done:
            return
        path.append(m)
        for n in sorted(graph[m]):
            visit(n)
        path.pop()
        done.add(m)

    for m in sorted(graph):
        visit(m)


# The folders from the ground up (docs/architecture.md): a folder imports only from folders
# before it, and only those its __init__ names.
LAYERS = (
    "io",
    "terms",
    "importer",
    "simulate",
    "fit",
    "calibration",
    "report",
    "protocols",
    "pipeline",
    "fleet",
    "diagnosis",
    "paper",
    "run",
)
VAGUE = {"utils", "util", "common", "misc", "helpers", "stuff", "lib", "core", "base_utils"}


def _folder(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and (PACKAGE / parts[1]).is_dir()) else ""


def _declared(folder: str) -> set[str]:
    """What a folder's __init__ says it may import: its docstring's second line."""
    doc = ast.get_docstring(ast.parse((PACKAGE / folder / "__init__.py").read_text()))
    lines = doc.splitlines()
    assert len(lines) >= 2 and lines[1].startswith("May import: ") and len(lines[0]) > 20, (
        f"gyrocal/{folder}/__init__.py: line 1 says what lives there, line 2 'May import: ...'"
    )
    said = lines[1].removeprefix("May import: ").rstrip(".")
    if said == "no other folder of gyrocal":
        return set()
    if said == "every other folder of gyrocal":
        return set(LAYERS) - {folder}
    return {name.strip() for name in said.split(",")}


def test_the_top_level_is_a_few_folders_each_a_layer():
    entries = sorted(
        p.name
        for p in PACKAGE.iterdir()
        if p.name not in ("__pycache__", "py.typed") and not p.name.endswith(".so")
    )
    assert len(entries) <= 15, entries
    assert {e for e in entries if (PACKAGE / e).is_dir()} == set(LAYERS)
    assert {e for e in entries if not (PACKAGE / e).is_dir()} == {"__init__.py", "__main__.py"}
    names = {p.stem for p in PACKAGE.rglob("*.py")} | {p.name for p in PACKAGE.rglob("*") if p.is_dir()}
    assert not names & VAGUE, names & VAGUE


def test_every_folder_imports_only_what_its_init_says_and_only_downwards():
    """A folder's modules import gyrocal modules of its own folder or of the folders its
    __init__ names, all of them lower in LAYERS: no import runs up, and no circle between
    folders can form."""
    modules = _modules()
    wrong = []
    for folder in LAYERS:
        allowed = _declared(folder)
        below = set(LAYERS[: LAYERS.index(folder)])
        assert allowed <= below or allowed == set(LAYERS) - {folder} and folder == LAYERS[-1], (
            f"gyrocal/{folder} says it may import {sorted(allowed - below)}, which are not below it"
        )
        for name, path in modules.items():
            if _folder(name) != folder:
                continue
            for target in _imports(name, path, modules):
                other = _folder(target)
                if other and other != folder and other not in allowed:
                    wrong.append(f"{name} -> {target}")
    assert not wrong, wrong


def test_no_module_compares_a_protocol_by_name_outside_the_registry():
    """Protocol names appear in comparisons only in the registry and the protocols' own
    packages (the simulator keys its rigs by name in tables, which is not a comparison)."""
    names = set(registry.names())
    own = {PACKAGE / "protocols" / "registry.py", *(PACKAGE / "protocols" / n / "protocol.py" for n in names)}
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path in own:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.Compare):
                continue
            for side in (node.left, *node.comparators):
                values = side.elts if isinstance(side, (ast.Tuple, ast.List, ast.Set)) else [side]
                if any(isinstance(v, ast.Constant) and v.value in names for v in values):
                    offenders.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    assert not offenders, offenders


def test_the_registry_knows_the_built_in_protocols_and_refuses_others():
    assert registry.names()[:3] == ("turntable", "servo", "sweep")
    for name in registry.names():
        p = registry.get(name)
        assert p.name == name and callable(p.segment) and callable(p.static)
    assert registry.get(None) is registry.get("turntable")
    # Only the turntable's calibrations feed batch outliers and drift pages; only the
    # servo has a calibration and validation of its own, and no known true rate.
    assert [n for n in registry.names() if registry.get(n).fleet_audits] == ["turntable"]
    assert [n for n in registry.names() if registry.get(n).calibrate] == ["servo"]
    assert [n for n in registry.names() if not registry.get(n).known_rate] == ["servo"]
    with pytest.raises(ConfigError, match="protocol 'hand' is not supported.*turntable, servo, sweep"):
        registry.get("hand")


def _parameters(function) -> list[str]:
    return [p.name for p in inspect.signature(function).parameters.values() if p.name != "self"]


@pytest.mark.parametrize("name", registry.BUILTIN)
def test_every_protocol_provides_the_typed_interface(name):
    """Each registered protocol is a :class:`registry.Protocol` whose methods take what the
    interface says: the abstract ones defined, the optional ones None or of the interface's
    signature, every attribute of the annotated type."""
    p = registry.get(name)
    assert isinstance(p, registry.Protocol) and not getattr(type(p), "__abstractmethods__", None)
    for method in ("segment", "static", "segmentation_settings"):
        assert _parameters(getattr(p, method)) == _parameters(getattr(registry.Protocol, method)), method
    hints = typing.get_type_hints(registry.Protocol, vars(registry) | _names_for_hints())
    optional = {"calibrate": 4, "validate": 2, "analysis": 1, "validation_figure": 1, "reading_blocks": 1}
    assert {k for k, v in hints.items() if "Callable" in str(v)} == set(optional)
    for member, arity in optional.items():
        own = getattr(p, member)
        assert own is None or len(_parameters(own)) == arity, member
    for member, hint in hints.items():
        if member in optional:
            continue
        value = getattr(p, member)
        kind = typing.get_args(hint)[0] if typing.get_origin(hint) is typing.ClassVar else hint
        assert _is_instance(value, kind), (member, value, kind)
    assert (p.defaults is None) == p.top_level_settings
    assert (p.segmentation_settings(None) is not None) == p.top_level_settings


def _names_for_hints() -> dict:
    """What the registry names only for the type checker."""
    import numpy as np
    import pandas as pd

    from gyrocal.calibration.file import Calibration
    from gyrocal.fit.validate import Validation
    from gyrocal.io.holds import Segmentation
    from gyrocal.io.log import RigLog

    return dict(
        np=np, pd=pd, Calibration=Calibration, Validation=Validation, Segmentation=Segmentation, RigLog=RigLog
    )


def _is_instance(value, hint) -> bool:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_is_instance(value, h) for h in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if origin is tuple:
        return isinstance(value, tuple) and all(isinstance(v, typing.get_args(hint)[0]) for v in value)
    if typing.is_typeddict(hint):
        return isinstance(value, dict) and set(value) == set(hint.__annotations__)
    return isinstance(value, origin or hint)


def test_a_protocol_registered_by_a_package_is_used_by_the_pipeline(tmp_path):
    """Adding a protocol is one registration: a log of it is segmented by its segmenter."""
    import numpy as np

    from gyrocal.pipeline.chain import segment_log
    from gyrocal.pipeline.config import Settings
    from gyrocal.protocols.turntable import protocol as turntable
    from gyrocal.simulate import TurntableProtocol, simulate_unit

    log = tmp_path / "u.parquet"
    simulate_unit(
        log,
        rig=TurntableProtocol.quick(temperatures=(20.0,), rates=(10.0, 100.0)),
        rng=np.random.default_rng(3),
    )
    seen = []

    class Renamed(turntable.Turntable):
        name = "renamed_turntable"

        def segment(self, log, settings):
            seen.append(log.path)
            return super().segment(log, settings)

    registry.register(Renamed())
    try:
        assert "renamed_turntable" in registry.names()
        seg = segment_log(log, Settings(), "renamed_turntable")
        assert seen and len(seg.observations) > 0
    finally:
        registry._REGISTRY.pop("renamed_turntable")


def test_the_analyse_job_fits_the_configured_model_once(tmp_path, monkeypatch):
    """Fit, validation and diagnosis share one fit of the configured model (the diagnosis
    fits only its candidates), and what they write is what separate stages write."""
    import numpy as np

    from gyrocal.diagnosis import evaluation
    from gyrocal.fit import thermal
    from gyrocal.pipeline import identify
    from gyrocal.pipeline.config import Settings
    from gyrocal.run import stages
    from gyrocal.simulate import TurntableProtocol, simulate_unit

    log = tmp_path / "u.parquet"
    simulate_unit(log, rig=TurntableProtocol.quick(), rng=np.random.default_rng(5))
    settings = Settings()
    meta = {"device": "U", "batch": "B", "session": "2026-01-01", "protocol": "turntable"}
    folder = tmp_path / "unit"
    stages.segment_stage(log, folder, settings, meta)
    configured = [t.spec_string() for t in settings.model.build().terms]
    fits = []
    original = thermal.fit_model

    def counting(model, *args, **kwargs):
        if [t.spec_string() for t in model.terms] == configured:
            fits.append(1)
        return original(model, *args, **kwargs)

    # the stages import the fit where they use it; the identification and the evaluation
    # hold their own name
    for module in (identify, thermal, evaluation):
        monkeypatch.setattr(module, "fit_model", counting)
    stages.analyse_stage(folder, settings, meta, record_failures=False)
    assert len(fits) == 1
    joint = {f: (folder / f).read_bytes() for f in ("calibration.json", "validation.json", "diagnosis.json")}

    # The same stages run one by one (the CLI's fit, validate, diagnose) write the same bytes.
    apart = tmp_path / "apart"
    stages.segment_stage(log, apart, settings, meta)
    stages.fit_stage(apart, settings, meta)
    stages.validate_stage(apart, settings)
    stages.diagnose_stage(apart, settings, meta)
    for name, data in joint.items():
        assert (apart / name).read_bytes() == data, name


def test_a_calibration_from_other_settings_is_refused_without_refitting(tmp_path):
    import numpy as np

    from gyrocal.io.errors import GyrocalError
    from gyrocal.pipeline.config import Settings
    from gyrocal.run import stages
    from gyrocal.simulate import TurntableProtocol, simulate_unit

    log = tmp_path / "u.parquet"
    simulate_unit(log, rig=TurntableProtocol.quick(), rng=np.random.default_rng(6))
    settings = Settings()
    meta = {"protocol": "turntable"}
    stages.segment_stage(log, tmp_path, settings, meta)
    stages.fit_stage(tmp_path, settings, meta)
    other = Settings.from_dict({"model": {"interpolation": "linear"}})
    with pytest.raises(GyrocalError, match="not fitted from these observations with these settings"):
        stages.validate_stage(tmp_path, other)
    stages.validate_stage(tmp_path, settings)  # its own settings: accepted


def test_the_schemas_name_the_registrys_protocols():
    """The manifest's protocol column and the config's per-protocol sections list the
    protocols the registry knows, no more and no fewer."""
    from gyrocal.io import schema

    manifest = schema.load("manifest")
    assert manifest["properties"]["protocol"]["enum"] == list(registry.names())
    config = schema.load("config")
    assert sorted(config["properties"]["spec"]["properties"]) == sorted(registry.names())
    own = [n for n in registry.names() if not registry.get(n).top_level_settings]
    assert sorted(config["properties"]["protocols"]["properties"]) == sorted(own)


_HOLDERS = ("list", "tuple", "Optional")  # annotations a bare dict may hide in


def _is_bare_dict(annotation: ast.expr | None) -> bool:
    """Whether a return annotation is a ``dict`` that says nothing of its keys: ``dict`` alone,
    or in a union (``dict | None``), a list or a tuple; a string annotation is read as one."""
    if isinstance(annotation, ast.Constant) and isinstance(annotation.value, str):
        annotation = ast.parse(annotation.value, mode="eval").body
    if isinstance(annotation, ast.Name):
        return annotation.id == "dict"
    if isinstance(annotation, ast.BinOp) and isinstance(annotation.op, ast.BitOr):
        return _is_bare_dict(annotation.left) or _is_bare_dict(annotation.right)
    if isinstance(annotation, ast.Subscript) and ast.unparse(annotation.value) in _HOLDERS:
        inner = annotation.slice
        return any(_is_bare_dict(e) for e in (inner.elts if isinstance(inner, ast.Tuple) else [inner]))
    return False


def test_no_public_function_returns_a_bare_dict():
    """A result that crosses a module boundary says what it holds: a record is a TypedDict or a
    frozen dataclass, a map is ``dict[K, V]``, a JSON document built or read whole is
    ``dict[str, Any]`` (a serialiser's ``to_dict`` among them)."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                and not node.name.startswith("_")
                and _is_bare_dict(node.returns)
            ):
                offenders.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.name}")
    assert not offenders, offenders
