"""Importing a wrapper whose engine is missing says which engine and how to
install it (checked in a subprocess in which the engine cannot be imported)."""

import subprocess
import sys

import pytest

CODE = """
import sys
sys.modules[{engine!r}] = None  # import {engine} now raises ImportError
try:
    import diffphys.{engine}
except ImportError as e:
    print(e)
else:
    print("imported")
"""


@pytest.mark.parametrize("engine", ["torch", "jax"])
def test_missing_engine_names_it_and_the_install_command(engine):
    out = subprocess.run([sys.executable, "-c", CODE.format(engine=engine)], capture_output=True,
                         text=True, check=True).stdout
    assert f"diffphys.{engine} needs {engine}" in out
    assert f'pip install "diffphys[{engine}]"' in out
    assert f'pip install "./crates/python[{engine}]"' in out


def test_numpy_alone_imports_diffphys():
    code = "import sys; sys.modules['torch'] = sys.modules['jax'] = None; import diffphys; print(diffphys.Poisson)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "Poisson" in out.stdout
