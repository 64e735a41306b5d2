"""masknet.registration.terms.methods: the method table, its views, the options it builds and the
default method; and that it needs no torch."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import subprocess
import sys

import pytest

from masknet.errors import MaskNetError
from masknet.registration.terms import methods
from masknet.registration.terms.methods import (
    GLOBAL_METHODS,
    METHOD_TABLE,
    METHOD_TITLES,
    METHODS,
    NETWORK_METHODS,
    PIPELINES,
    Method,
    adapter,
    default_method,
    method_options,
)
from masknet.registration.terms.options import (
    FGROptions,
    ICPCriteria,
    NetworkOptions,
    Open3DICPOptions,
    PointNetLKOptions,
    RANSACOptions,
    RobustOptions,
)

# The table as the docs state it, written out independently: name -> (title, options,
# default max_iterations, uses init, kind).
_EXPECTED = {
    "auto": ("ICP (auto)", RobustOptions, None, False, "pipeline"),
    "icp": ("ICP", ICPCriteria, 10, True, "backend"),
    "robust": ("ICP (robust)", RobustOptions, None, False, "pipeline"),
    "open3d-icp": ("Open3D-ICP", Open3DICPOptions, 10, True, "backend"),
    "pointnetlk": ("PointNetLK", PointNetLKOptions, 10, True, "network"),
    "dcp": ("DCP", NetworkOptions, 1, True, "network"),
    "prnet": ("PRNet", NetworkOptions, 3, True, "network"),
    "pcrnet": ("PCRNet", NetworkOptions, 8, True, "network"),
    "rpmnet": ("RPM-Net", NetworkOptions, 5, True, "network"),
    "open3d-ransac": ("Open3D-RANSAC", RANSACOptions, None, False, "backend"),
    "open3d-fgr": ("Open3D-FGR", FGROptions, None, False, "backend"),
}


def test_the_table_holds_the_documented_methods():
    assert list(METHOD_TABLE) == list(_EXPECTED)
    for name, entry in METHOD_TABLE.items():
        assert isinstance(entry, Method) and entry.name == name
        title, options, iterations, uses_init, kind = _EXPECTED[name]
        assert (entry.title, entry.options, entry.default_iterations) == (
            title,
            options,
            iterations,
        ), name
        assert (entry.uses_init, entry.kind) == (uses_init, kind), name
    assert len(set(METHOD_TITLES.values())) == len(METHOD_TITLES)  # titles tell them apart


def test_the_views_are_exactly_views_of_the_table():
    """Each view recomputed from the entries' fields, in table order."""
    entries = list(METHOD_TABLE.values())
    assert METHODS == tuple(e.name for e in entries)
    assert METHOD_TITLES == {e.name: e.title for e in entries}
    assert list(METHOD_TITLES) == list(METHODS)  # same order
    assert NETWORK_METHODS == tuple(e.name for e in entries if e.kind == "network")
    assert PIPELINES == tuple(e.name for e in entries if e.kind == "pipeline")
    assert GLOBAL_METHODS == tuple(
        e.name for e in entries if e.kind == "backend" and not e.uses_init
    )
    # and against the documented lists, so that a wrong field would show too
    assert NETWORK_METHODS == ("pointnetlk", "dcp", "prnet", "pcrnet", "rpmnet")
    assert PIPELINES == ("auto", "robust")
    assert GLOBAL_METHODS == ("open3d-ransac", "open3d-fgr")


@pytest.mark.parametrize("name", list(METHOD_TABLE))
def test_every_adapter_imports_to_a_callable_of_its_kind(name):
    module_name, function = METHOD_TABLE[name].adapter.split(":")
    # a back-end's adapter module lives in backends/; a pipeline is its own adapter
    kind = METHOD_TABLE[name].kind
    home = (
        "masknet.registration." if kind == "pipeline" else "masknet.registration.solvers.backends."
    )
    assert module_name.startswith(home)
    module = importlib.import_module(module_name)
    assert function in module.__all__  # a public name of its module
    run = adapter(name)
    assert callable(run) and run is getattr(module, function)
    parameters = list(inspect.signature(run).parameters)
    if METHOD_TABLE[name].kind == "pipeline":  # base.Pipeline
        assert parameters == [
            "template",
            "source",
            "nets",
            "models",
            "options",
            "times",
            "precision",
        ]
    else:  # base.Backend
        assert parameters == ["template", "source", "mask", "source_mask", "options"]


def test_the_network_entries_match_the_network_classes():
    from masknet.models import REGISTRATION_NETWORKS

    assert set(NETWORK_METHODS) == set(REGISTRATION_NETWORKS)
    for name in NETWORK_METHODS:
        assert (
            METHOD_TABLE[name].default_iterations == REGISTRATION_NETWORKS[name].default_iterations
        ), name
        assert issubclass(METHOD_TABLE[name].options, NetworkOptions), name


@pytest.mark.parametrize("name", list(METHOD_TABLE))
def test_method_options_defaults(name):
    entry = METHOD_TABLE[name]
    options = method_options(name, None, {})
    assert type(options) is entry.options
    fields = {f.name: f.default for f in dataclasses.fields(entry.options)}
    if "max_iterations" in fields:
        # the table's default where it has one, else the class's own
        expected = (
            fields["max_iterations"]
            if entry.default_iterations is None
            else entry.default_iterations
        )
        assert options.max_iterations == expected, name
        assert options.max_iterations is not None, name  # every method runs a budget
    # every other field is the class default
    for field, default in fields.items():
        if field != "max_iterations":
            assert getattr(options, field) == default, (name, field)


def test_method_options_keywords_and_refusals():
    assert method_options("icp", None, {"max_iterations": 3}).max_iterations == 3
    # max_iterations=None spelled as a keyword still means the table's default
    assert method_options("dcp", None, {"max_iterations": None}).max_iterations == 1
    assert method_options("prnet", None, {}).max_iterations == 3
    given = ICPCriteria(max_iterations=7)
    assert method_options("icp", given, {}) is given
    with pytest.raises(MaskNetError, match=r"unknown option\(s\) for method 'icp': tolerance"):
        method_options("icp", None, {"tolerance": 1e-3})
    with pytest.raises(MaskNetError, match=r"method 'dcp' takes options=NetworkOptions\(\.\.\.\)"):
        method_options("dcp", ICPCriteria(), {})
    with pytest.raises(MaskNetError, match="not both"):
        method_options("icp", given, {"max_iterations": 3})
    with pytest.raises(MaskNetError, match="max_iterations must be an integer >= 0"):
        method_options("icp", None, {"max_iterations": -1})  # checked when built


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (ICPCriteria(), "icp"),
        (Open3DICPOptions(), "open3d-icp"),
        (PointNetLKOptions(), "pointnetlk"),  # a subclass of NetworkOptions, but only LK's
        (RANSACOptions(), "open3d-ransac"),
        (FGROptions(), "open3d-fgr"),
        (RobustOptions(), "auto"),  # serves auto and robust: the default, which escalates
    ],
)
def test_typed_options_choose_the_method(options, expected):
    assert default_method(None, options) == expected
    assert default_method("robust", options) == "robust"  # a named method wins


def test_default_method_rules():
    with pytest.raises(MaskNetError, match="NetworkOptions serves dcp, prnet, pcrnet, rpmnet"):
        default_method(None, NetworkOptions())
    with pytest.raises(MaskNetError, match="options= takes a method's options, got dict"):
        default_method(None, {"max_iterations": 3})
    assert default_method(None, None) == "auto"  # no other argument chooses the method
    assert default_method("dcp", None) == "dcp"


def test_importing_the_table_needs_no_torch():
    code = (
        "import sys\n"
        "import masknet.registration.terms.methods as m\n"
        "m.method_options('icp', None, {}); m.default_method(None, None)\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert out.stdout.strip() == "False", out.stdout + out.stderr
    assert methods.__name__ == "masknet.registration.terms.methods"


def test_a_given_network_options_object_runs_the_tables_iterations(known_pairs, shipped_pointnetlk):
    from masknet import register

    template, source = known_pairs.template[0], known_pairs.source[0]
    by_keyword = register(
        template, source, method="pointnetlk", use_mask=False, network=shipped_pointnetlk
    )
    by_object = register(
        template,
        source,
        method="pointnetlk",
        use_mask=False,
        options=PointNetLKOptions(network=shipped_pointnetlk),
    )
    assert by_object.info["iterations"] == by_keyword.info["iterations"]
    assert (by_object.transform == by_keyword.transform).all()
