"""Every public name has a docstring that help() shows (with dtypes and the
errors raised where it computes something) and an entry in the type stubs
that ship with the installed package."""

import ast
import inspect
import pydoc
from pathlib import Path

import pytest

import diffphys
import diffphys._native as native
import diffphys.jax
import diffphys.torch

PACKAGE = Path(diffphys.__file__).parent
EXCEPTIONS = {n for n in diffphys.__all__ if n.endswith("Error")}
# Functions that hand out solvers: no arrays in or out.
FACTORIES = {"poisson", "projection"}


def public(module):
    return [(module.__name__, name, getattr(module, name)) for name in module.__all__]


NAMES = public(diffphys) + public(diffphys.jax) + public(diffphys.torch)
CLASSES = [native.Poisson, native.Projection, native.FlowStep]


def members(cls):
    """The public methods and properties a class defines itself."""
    return {n: v for n, v in vars(cls).items() if not n.startswith("_")}


@pytest.mark.parametrize("module,name,obj", NAMES, ids=[f"{m}.{n}" for m, n, _ in NAMES])
def test_public_name_has_a_docstring_help_shows(module, name, obj):
    doc = inspect.getdoc(obj)
    assert doc and len(doc) > 40, f"{module}.{name} has no docstring"
    assert doc.splitlines()[0] in pydoc.render_doc(obj, renderer=pydoc.plaintext)
    if name in EXCEPTIONS:
        return
    assert "Raises" in doc, f"{module}.{name}: the docstring names no error raised"
    if name not in FACTORIES:
        assert "float32" in doc or "float64" in doc, f"{module}.{name}: no dtype in the docstring"


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_method_and_property_has_a_docstring(cls):
    missing = [n for n, v in members(cls).items() if not inspect.getdoc(v)]
    assert not missing, f"{cls.__name__}: no docstring for {missing}"
    # The constructor's signature is visible to help() and inspect.
    assert "shape" in str(inspect.signature(cls))


def stub_names():
    """Top-level names of _native.pyi, and the member names of each class."""
    tree = ast.parse((PACKAGE / "_native.pyi").read_text())
    top, classes = set(), {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            top.add(node.name)
            classes[node.name] = {
                n.name for n in node.body if isinstance(n, ast.FunctionDef) and not n.name.startswith("_")
            }
        elif isinstance(node, ast.FunctionDef):
            top.add(node.name)
    return top, classes


def test_the_stubs_and_the_marker_are_installed():
    assert (PACKAGE / "py.typed").is_file()
    assert (PACKAGE / "_native.pyi").is_file()


def test_every_native_name_has_a_stub_entry_and_no_stub_is_stale():
    top, classes = stub_names()
    runtime = {n for n in dir(native) if not n.startswith("_")}
    assert runtime - top == set(), "public names of diffphys._native without a stub"
    assert top - runtime == set(), "stub entries with nothing at runtime"
    for cls in CLASSES:
        assert set(members(cls)) == classes[cls.__name__], cls.__name__


def test_the_wrappers_are_annotated():
    for module, name, obj in NAMES:
        if inspect.isfunction(obj):
            hints = inspect.signature(obj)
            assert hints.return_annotation is not inspect.Signature.empty, f"{module}.{name}"
