"""The README's first code block runs as written (issue 31: it named a file that is not there and
variables it never defined)."""

from __future__ import annotations

import pathlib
import re

import numpy as np

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_the_first_code_block_runs_as_written(tmp_path, monkeypatch):
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Using it"):]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(block, "README.md (Using it)", "exec"), scope)
    assert (tmp_path / "out.bvh").is_file()
    assert scope["clip"].positions.shape == (scope["motion"].num_frames, scope["skel"].num_joints, 3)
    np.testing.assert_allclose(np.asarray(scope["q_sharded"]), np.asarray(scope["motion"].rotations))
