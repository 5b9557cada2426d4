"""A non-editable install runs: `cellctl --version`, and `cellctl serve --demo-cycles 2` on the simulated cell.

The wheel is built from a copy of the tree (so the checkout is left as it was) and installed, without
its dependencies, into a fresh venv that sees this venv's packages through a .pth line: nothing is
downloaded, and the cellctl that runs is the installed one, with its packaged config, not the checkout.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest
from service_test_support import free_port, sim_toml

ROOT = Path(__file__).resolve().parents[2]
TREE = ("pyproject.toml", "README.md", "MANIFEST.in", "LICENSE", "src", "drivers", "config")


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bin folder of a fresh venv with cellctl installed from a wheel of this tree."""
    tmp = tmp_path_factory.mktemp("pkg")
    tree = tmp / "tree"
    tree.mkdir()
    for name in TREE:
        src = ROOT / name
        if not src.exists():
            continue
        if src.is_dir():
            shutil.copytree(src, tree / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy2(src, tree / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp / "dist"), str(tree)], check=True, timeout=300)
    wheel = next((tmp / "dist").glob("cellctl-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    subprocess.run([*pip, "--python", str(py), "install", "--no-deps", "--no-index", str(wheel)], check=True, timeout=300)
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    (Path(site) / "_cellctl_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # numpy, fastapi, ...
    return venv / "bin"


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_") and k != "PYTHONPATH"}
    return {**env, "PYTHONDONTWRITEBYTECODE": "1"}


def test_the_installed_package_is_not_the_checkout_and_knows_its_version(installed: Path, tmp_path: Path) -> None:
    from importlib.metadata import version

    where = subprocess.run([str(installed / "python"), "-c", "import cellctl; print(cellctl.__file__)"],
                           capture_output=True, text=True, cwd=tmp_path, env=_env(), check=True).stdout  # fmt: skip
    assert Path(where.strip()).is_relative_to(installed.parent)
    run = subprocess.run([str(installed / "cellctl"), "--version"], capture_output=True, text=True, cwd=tmp_path, env=_env())
    assert run.returncode == 0 and run.stdout.strip() == f"cellctl {version('cellctl')}", run.stderr
    run = subprocess.run([str(installed / "python"), "-m", "cellctl", "--version"],
                         capture_output=True, text=True, cwd=tmp_path, env=_env())  # fmt: skip
    assert run.returncode == 0 and run.stdout.strip() == f"cellctl {version('cellctl')}", run.stderr


def test_the_default_config_is_the_packaged_simulated_cell(installed: Path, tmp_path: Path) -> None:
    run = subprocess.run([str(installed / "cellctl"), "config", "check"], capture_output=True, text=True, cwd=tmp_path, env=_env())
    assert run.returncode == 0, run.stderr
    path = Path(run.stdout.splitlines()[0].removeprefix("OK: "))
    assert path.is_relative_to(installed.parent) and path.name == "sim.toml" and "mode sim" in run.stdout
    assert path.read_bytes() == (ROOT / "config" / "sim.toml").read_bytes()


def test_installed_serve_runs_the_demo_on_the_simulated_cell(installed: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "cell.toml"  # the packaged sim.toml with the PLC and OPC UA off, the calibration from the twin
    cfg.write_text(sim_toml(free_port()))
    port = free_port()  # --port overrides [api] port
    proc = subprocess.Popen([str(installed / "cellctl"), "--config", str(cfg), "serve", "--port", str(port), "--demo-cycles", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path, env=_env())  # fmt: skip
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        end = time.monotonic() + 240
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if line.startswith("demo: ") and " installed;" in line or time.monotonic() > end:
                break
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = None
    text = "\n".join(lines)
    assert f"cellctl serving on http://127.0.0.1:{port}/ (mode sim)" in text, text
    assert "demo: 2 of 2 installed" in text, text
    assert len(re.findall(r"(?m)^\s+\d+ \S+\s+done ", text)) == 2, text  # cycle, recipe, state
    assert "Traceback" not in text
    assert rc == 130
    assert (tmp_path / "var").is_dir()  # the default --workdir is the current folder


def test_the_installed_abb_driver_has_its_rapid_modules_and_their_instructions(installed: Path, tmp_path: Path) -> None:
    """The integrator of an installed cell loads the RAPID modules as the driver's README (beside them) says."""
    run = subprocess.run([str(installed / "python"), "-c", "import abb_robot, pathlib; print(pathlib.Path(abb_robot.__file__).parent)"],
                         capture_output=True, text=True, cwd=tmp_path, env=_env(), timeout=60)  # fmt: skip
    assert run.returncode == 0, run.stderr
    folder = Path(run.stdout.strip())
    assert folder.is_relative_to(installed.parent), folder
    rapid = sorted(p.name for p in folder.rglob("*.mod"))
    assert rapid and (folder / "README.md").is_file(), (rapid, sorted(p.name for p in folder.iterdir()))
    readme = (folder / "README.md").read_text(encoding="utf-8")
    assert all(name in readme for name in rapid), rapid
