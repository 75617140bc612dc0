"""Writes an executed notebook as a docs page: markdown cells as they are, code
cells as python blocks, printed output as text blocks, figures as PNG files.

Usage (from the repository root, in a venv with nbformat):

    DIFFPHYS_NOTEBOOK_SMALL=0 jupyter nbconvert --to notebook --execute \\
        --output /tmp/executed.ipynb notebooks/solver_in_the_loop_torch.ipynb
    python notebooks/export_to_docs.py /tmp/executed.ipynb docs/python-notebook.md \\
        docs/img/notebook

The page links the figures relative to itself.
"""

import base64
import os
import sys

import nbformat


def export(notebook, page, images):
    nb = nbformat.read(notebook, as_version=4)
    os.makedirs(images, exist_ok=True)
    rel = os.path.relpath(images, os.path.dirname(page))
    parts, figure = [], 0
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            parts.append(cell.source)
            continue
        parts.append(f"```python\n{cell.source}\n```")
        for out in cell.get("outputs", []):
            if out.output_type == "stream":
                parts.append(f"```text\n{out.text.rstrip()}\n```")
            elif out.output_type == "error":
                raise SystemExit(f"the notebook failed: {out.ename}: {out.evalue}")
            elif "image/png" in out.get("data", {}):
                figure += 1
                name = f"figure-{figure}.png"
                with open(os.path.join(images, name), "wb") as f:
                    f.write(base64.b64decode(out.data["image/png"]))
                parts.append(f"![figure {figure}]({rel}/{name})")
    with open(page, "w", encoding="utf-8") as f:
        f.write("\n\n".join(parts) + "\n")
    print(f"wrote {page} and {figure} figures in {images}")


if __name__ == "__main__":
    export(*sys.argv[1:4])
