"""The Makefile's choice of python: requires-python in pyproject.toml is the one place the supported
versions are stated; the Makefile reads it, picks an interpreter within it, and says what it needs
and what it found when there is none, or when an existing .venv's python is out of range or gone."""

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
V = sys.version_info


def make(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-s", "--no-print-directory", "-C", str(ROOT), *args],
                          capture_output=True, text=True, timeout=60)


def requires(spec: str) -> bool:
    """Whether this interpreter is within `spec`, as the Makefile's check decides it."""
    rule = 'check-spec: ; @"$(PYTHON)" -c "$$PYCHECK" \'$(SPEC)\''
    return make("--eval", rule, "check-spec", f"PYTHON={sys.executable}", f"SPEC={spec}").returncode == 0


def test_the_makefile_reads_requires_python_from_pyproject():
    spec = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    out = make("--eval", "print-spec: ; @echo '$(REQUIRES_PYTHON)'", "print-spec")
    assert out.stdout.strip() == spec
    assert requires(spec), f"the test suite's own Python {sys.version} is outside {spec}"


def test_version_specifiers_are_read_as_pip_reads_them():
    major, minor, micro = V[:3]
    assert requires(f">={major}.{minor},<{major}.{minor + 1}")
    assert not requires(f">={major}.{minor + 1}")
    assert not requires(f"<{major}.{minor}")
    assert requires(f"=={major}.{minor}.*") and not requires(f"!={major}.{minor}.*")
    assert requires(f"~={major}.{minor}") and requires(f"=={major}.{minor}.{micro}")
    assert requires(f"<={major}.{minor}") == (micro == 0)  # 3.13 is 3.13.0, as in PEP 440


def test_make_python_names_the_interpreter_it_picks(tmp_path):
    out = make("python", f"PYTHON={sys.executable}", f"VENV={tmp_path / 'venv'}")
    assert out.returncode == 0, out.stderr
    assert f"{sys.executable}: Python {V.major}.{V.minor}.{V.micro}" in out.stdout


def test_no_usable_python_says_what_it_needs_and_what_it_found(tmp_path):
    out = make("python", f"PYTHON={sys.executable}", f"VENV={tmp_path / 'venv'}", "REQUIRES_PYTHON=>=3.98,<3.100")
    assert out.returncode != 0
    assert 'needs Python 3.98-3.99 (requires-python ">=3.98,<3.100" in pyproject.toml)' in out.stderr
    assert f"found: {sys.executable} {V.major}.{V.minor}.{V.micro}." in out.stderr
    assert "make PYTHON=/path/to/python3.99 python" in out.stderr
    out = make("python", "PYTHON=python3.97", f"VENV={tmp_path / 'venv'}")
    assert out.returncode != 0 and "not found: python3.97" in out.stderr


def fake_venv(path: Path, made_with: str) -> Path:
    """A venv at `path` whose python is this interpreter's base, recorded as made with `made_with`."""
    real = Path(os.path.realpath(sys.executable))
    (path / "bin").mkdir(parents=True)
    (path / "bin" / "python").symlink_to(real)
    (path / "pyvenv.cfg").write_text(f"home = {real.parent}\ninclude-system-site-packages = false\nversion = {made_with}\n")
    return path


def test_a_venv_out_of_range_is_named_with_its_version(tmp_path):
    venv = fake_venv(tmp_path / "venv", f"{V.major}.{V.minor}.{V.micro}")
    out = make("python", f"VENV={venv}", "REQUIRES_PYTHON=>=3.98,<3.100")
    assert out.returncode != 0
    assert f"{venv} was made with Python {V.major}.{V.minor}.{V.micro}; Neuro-IK Lab needs Python 3.98-3.99" in out.stderr
    assert "run make clean" in out.stderr


def test_a_venv_whose_python_was_upgraded_or_removed_is_named(tmp_path):
    venv = fake_venv(tmp_path / "upgraded", "3.5.1")
    out = make("python", f"VENV={venv}")
    assert out.returncode != 0
    assert f"{venv} was made with Python 3.5.1 but its python is now {V.major}.{V.minor}.{V.micro}" in out.stderr
    gone = tmp_path / "gone"
    (gone / "bin").mkdir(parents=True)
    (gone / "bin" / "python").symlink_to(tmp_path / "no-such-python")
    out = make("install", f"VENV={gone}")
    assert out.returncode != 0
    assert f"{gone} exists but {gone}/bin/python is missing" in out.stderr
    assert not (gone / ".installed-stamp").exists()
