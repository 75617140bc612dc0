"""The README's "From Python" snippets run as written (and train)."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[3] / "README.md"


def snippets():
    text = README.read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    return [b for b in blocks if "diffphys" in b]


@pytest.mark.parametrize("code", snippets(), ids=["jax", "torch"])
def test_snippet_runs_and_trains(code):
    scope = {}
    exec(compile(code, str(README), "exec"), scope)
    if "loss" in scope and callable(scope["loss"]):  # JAX: loss is a function of b
        assert scope["loss"](scope["b"]) < 1e-2 * scope["loss"](0.0 * scope["b"])
    else:  # PyTorch: loss is the last step's value
        first = (scope["p_target"]).pow(2).mean()
        assert scope["loss"].item() < 1e-2 * first.item()
