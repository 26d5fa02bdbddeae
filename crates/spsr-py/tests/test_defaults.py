"""The keyword defaults of the Python functions are the library's (`spsr._spsr._defaults()`,
built from `Params::default()`, `TrimParams::default()`, `NormalParams::default()` and
`EvalOptions::default()`), in the signatures and in the docstrings."""

import inspect
import re

import pytest

import spsr
from spsr import _spsr

# Keywords with no library default behind them: data, and choices the Python layer makes.
PYTHON_ONLY = {
    "reconstruct": {"normals", "colors", "weights", "point_attributes", "threads", "keep_implicit"},
    "trim": {"threads"},
    "estimate_normals": {"orient", "viewpoint", "scan_origins", "threads", "return_info"},
    "eval": {"reference", "sphere", "threads"},
    "render": {"faces", "color", "highlight", "threads"},
}

# Keywords whose Python default is None, meaning "the library's default, adjusted": the
# docstring says what it is. full_depth: the library's 5, or the depth when that is smaller.
NONE_MEANS_LIBRARY = {
    # None: the library's 8, unless width= sets the depth (both together are an error).
    ("reconstruct", "depth"),
    ("reconstruct", "full_depth"),
    # None: the library's 1.5, and a value given turns the noise adaptation off.
    ("reconstruct", "samples_per_node"),
    # None: the library's "adaptive", or "off" when samples_per_node or point_weight is given.
    ("reconstruct", "noise"),
}

DEFAULTS = _spsr._defaults()


def keywords(name):
    """The keyword parameters (with defaults) of spsr.<name>."""
    sig = inspect.signature(getattr(spsr, name))
    return {p.name: p.default for p in sig.parameters.values() if p.default is not inspect.Parameter.empty}


def documented_defaults(name):
    """`name : type, default VALUE` lines of the numpydoc Parameters section, by keyword."""
    doc = inspect.getdoc(getattr(spsr, name))
    out = {}
    for line in doc.splitlines():
        m = re.match(r"^(\w+(?:, \w+)*) : .*, default (.+)$", line)
        if m:
            for kw in m.group(1).split(", "):
                out[kw] = m.group(2)
    return out


def same(python, library):
    if isinstance(library, bool) or library is None or isinstance(python, bool):
        return python is library or python == library and type(python) is type(library)
    return python == library


@pytest.mark.parametrize("name", sorted(PYTHON_ONLY))
def test_every_keyword_is_accounted_for(name):
    """A new keyword must be added to `_defaults()` or to PYTHON_ONLY."""
    lib = set(DEFAULTS[name])
    assert set(keywords(name)) == lib | PYTHON_ONLY[name]
    assert not lib & PYTHON_ONLY[name]


@pytest.mark.parametrize("name", sorted(PYTHON_ONLY))
def test_signature_defaults_are_the_librarys(name):
    for kw, python in keywords(name).items():
        if kw in PYTHON_ONLY[name]:
            continue
        library = DEFAULTS[name][kw]
        if (name, kw) in NONE_MEANS_LIBRARY:
            assert python is None, kw
            doc = inspect.getdoc(getattr(spsr, name))
            assert f"Default {library}" in doc, kw
        else:
            assert same(python, library), f"spsr.{name}({kw}={python!r}): the library's default is {library!r}"


@pytest.mark.parametrize("name", sorted(PYTHON_ONLY))
def test_documented_defaults_are_the_librarys(name):
    documented = documented_defaults(name)
    assert documented, "no `name : type, default value` lines found"
    for kw, text in documented.items():
        library = DEFAULTS[name][kw] if kw in DEFAULTS[name] else keywords(name)[kw]
        if isinstance(library, bool):
            assert text == str(library), kw
        elif isinstance(library, str):
            assert text.strip("\"'") == library, kw
        else:
            assert float(text.replace("_", "")) == library, kw


def test_defaults_match_the_documented_values():
    """A few values by hand, so that a wrong `_defaults()` cannot pass the tests above."""
    r = DEFAULTS["reconstruct"]
    assert (r["depth"], r["full_depth"], r["degree"], r["boundary"]) == (8, 5, 1, "neumann")
    assert (r["samples_per_node"], r["scale"], r["data_pull"]) == (1.5, 1.1, 32.0)
    # None: 2 cycles of 4 sweeps at degree 1, 1 cycle of 8 at degree 2 (Params::cycles()).
    assert r["iters"] is None and r["cycles"] is None and r["solver"] == "cascadic"
    assert r["confidence"] is False and r["confidence_property"] is None and r["attributes"] is True
    assert (r["noise"], r["keep_outliers"], r["keep_normals"]) == ("adaptive", False, False)
    assert r["width"] is None and r["grid_res"] is None
    assert DEFAULTS["trim"] == {"threshold": "auto", "min_island_area": 0.001, "hole_area": 0.001}
    assert DEFAULTS["estimate_normals"] == {"neighbours": None}
    assert DEFAULTS["eval"] == {"samples": 1_000_000, "seed": 1}
    assert DEFAULTS["render"] == {"view": "iso", "size": (800, 800)}
