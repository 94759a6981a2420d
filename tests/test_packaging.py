"""pyproject.toml declares what environment.txt installs, with the same pins."""
import re
from pathlib import Path

import pytest

from ncs_lite.sweeps import SUBMITIT_VERSION

tomllib = pytest.importorskip("tomllib")          # Python 3.11 on

REPO = Path(__file__).resolve().parents[1]


def requirements(lines):
    """{name: specifier} of pip requirement lines (comments, blanks and `-e .` skipped)."""
    out = {}
    for line in lines:
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            name = re.match(r"[A-Za-z0-9_.\-]+", line).group(0)
            out[name.lower()] = line[len(name):].replace(" ", "")
    return out


def test_pyproject_declares_environment_txt_with_its_pins():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    declared = requirements(project["dependencies"])
    extras = {k: requirements(v) for k, v in project["optional-dependencies"].items()}
    assert declared["torch"] == "==2.13.0"                        # a CPU build; any other pulls CUDA
    for extra in extras.values():
        assert not declared.keys() & extra.keys()                # each package in one place
    environment = requirements((REPO / "environment.txt").read_text().splitlines())
    everything = {**declared, **extras["notebooks"], **extras["test"]}
    assert everything == environment
    assert extras["sweeps"] == {"submitit": f"=={SUBMITIT_VERSION}"}
