"""The Python snippets of the README ("From Python") and of the Python guide
(docs/python.md) run as written (and train)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
PAGES = [ROOT / "README.md", ROOT / "docs" / "python.md"]


def snippets():
    found = []
    for page in PAGES:
        blocks = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.S)
        training = [b for b in blocks if "diffphys.jax" in b or "diffphys.torch" in b]
        for code in training:
            engine = "jax" if "diffphys.jax" in code else "torch"
            found.append(pytest.param(page, code, id=f"{page.name}-{engine}"))
    return found


@pytest.mark.parametrize("page,code", snippets())
def test_snippet_runs_and_trains(page, code):
    scope = {}
    exec(compile(code, str(page), "exec"), scope)
    if "loss" in scope and callable(scope["loss"]):  # JAX: loss is a function of b
        assert scope["loss"](scope["b"]) < 1e-2 * scope["loss"](0.0 * scope["b"])
    else:  # PyTorch: loss is the last step's value
        first = (scope["p_target"]).pow(2).mean()
        assert scope["loss"].item() < 1e-2 * first.item()


def test_every_page_has_both_engines():
    ids = [p.id for p in snippets()]
    for page in PAGES:
        assert f"{page.name}-jax" in ids and f"{page.name}-torch" in ids, ids
