"""`cellctl serve` refusing to start: the message names the setting the cause points at, and the exit status says
whether a restart can help (2: a configuration problem, on which deploy/cellctl.service does not restart).

- A server that cannot listen: an address not of this machine names `[api] host` / `[opcua] host` (not the port),
  a privileged port names the port and CAP_NET_BIND_SERVICE; the OS's own bind is the judge (EADDRNOTAVAIL, EACCES).
  A bind to an address not on this machine fails at once and sends nothing.
- `serve --port` is held to the file's rule that [api], [plc] and [opcua] each have their own port.
- `[store] path` in a folder the service may not write (chattr +i as root, else chmod; the OS's write is the judge),
  a lock or database file it may not write, a folder at `[store] path`, a file at `calibration.directory`: one line
  naming the setting and the fix, exit 2; `config check --secrets` refuses the same."""

from __future__ import annotations

import errno
import os
import re
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from service_test_support import sim_toml
from shared_support import free_port

pytestmark = pytest.mark.timeout(240)
FOREIGN = ("192.0.2.1", "10.255.255.1")  # TEST-NET-1 and an address of a private net: not this machine's
STORE_FIX = 'change [store] path to a file in a folder the service can write (e.g. path = "var/cellctl.db")'
NOCAPS = ["setpriv", "--bounding-set=-all", "--inh-caps=-all"]


def _cellctl(workdir: Path, *args: str, prefix: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CELLCTL_")}
    try:
        return subprocess.run([*prefix, sys.executable, "-m", "cellctl", *args], cwd=workdir, capture_output=True,
                              text=True, timeout=180, env=env)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail(f"cellctl {' '.join(args)} did not refuse: it kept running")


def _serve(workdir: Path, text: str, *options: str, prefix: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    cfg = workdir / "cell.toml"
    cfg.write_text(text, encoding="utf-8")
    return _cellctl(workdir, "--config", str(cfg), "serve", "--workdir", str(workdir), *options, prefix=prefix)


def _check(workdir: Path) -> subprocess.CompletedProcess[str]:
    return _cellctl(workdir, "--config", str(workdir / "cell.toml"), "config", "check", "--secrets", "--workdir", str(workdir))


def _last(done: subprocess.CompletedProcess[str], *, others_trace: bool = False) -> str:
    """The last line of stderr, cellctl's refusal; ``others_trace``: a library logged its own trace before (asyncua)."""
    lines = done.stderr.strip().splitlines()
    assert lines and (others_trace or "Traceback" not in done.stderr), done.stderr
    return lines[-1]


def _foreign_address() -> str:
    """An IPv4 address this machine has not: the OS refuses a bind to it with EADDRNOTAVAIL (nothing is sent)."""
    for address in FOREIGN:
        with socket.socket() as sock:
            try:
                sock.bind((address, 0))
            except OSError as err:
                if err.errno == errno.EADDRNOTAVAIL:
                    return address
    pytest.skip(f"this machine has {FOREIGN}, or its OS answers otherwise")


def _set(text: str, section: str, key: str, value: str) -> str:
    """``key = value`` in the TOML ``[section]`` of ``text`` (its first such line after the header)."""
    out, n = re.subn(rf"(?ms)^(\[{re.escape(section)}\][^\[]*?^){key} = [^\n]*$", rf"\g<1>{key} = {value}", text, count=1)
    assert n == 1, (section, key)
    return out


def _enabled(text: str, server: str) -> str:
    out = text.replace(f"[{server}]\nenabled = false", f"[{server}]\nenabled = true", 1)
    assert out != text, server
    return out


def test_an_api_host_not_of_this_machine_names_api_host(tmp_path: Path) -> None:
    host, port = _foreign_address(), free_port()
    done = _serve(tmp_path, _set(sim_toml(port), "api", "host", f'"{host}"'))
    assert done.returncode == 1, done.stderr  # an address may yet come up (a slow interface): a restart can help
    assert _last(done) == (f"error: the REST API cannot listen on {host}:{port}: [api] host '{host}' is not an address "
                           "of this machine (Cannot assign requested address); set it to one of them")  # fmt: skip
    assert "cellctl serving" not in done.stdout


def test_an_opcua_host_not_of_this_machine_names_opcua_host(tmp_path: Path) -> None:
    host, port = _foreign_address(), free_port()
    text = _set(_set(_enabled(sim_toml(free_port()), "opcua"), "opcua", "host", f'"{host}"'), "opcua", "port", str(port))
    done = _serve(tmp_path, text)
    assert done.returncode == 1, done.stderr
    assert _last(done, others_trace=True) == (f"error: the OPC UA server cannot start: the OPC UA server cannot listen on {host}:{port}: "
                           f"[opcua] host '{host}' is not an address of this machine (Cannot assign requested address); "
                           "set it to one of them")  # fmt: skip


@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv")
def test_a_privileged_api_port_names_the_port_and_the_capability(tmp_path: Path) -> None:
    os.chmod(tmp_path, 0o755)
    probe = subprocess.run([*NOCAPS, sys.executable, "-c", "import socket; socket.socket().bind(('127.0.0.1', 1))"],
                           capture_output=True, text=True)  # fmt: skip
    if "PermissionError" not in probe.stderr:  # the truth: without capabilities, port 1 is refused (EACCES)
        pytest.skip(f"this OS lets a process without capabilities bind port 1: {probe.stderr}")
    done = _serve(tmp_path, sim_toml(1), prefix=tuple(NOCAPS))
    assert done.returncode == 1, done.stderr
    assert _last(done) == ("error: the REST API cannot listen on 127.0.0.1:1: cannot listen on 127.0.0.1:1 ([api] port): "
                           "Permission denied; choose a port of 1024 or above, or give the service CAP_NET_BIND_SERVICE "
                           "(as deploy/cellctl.service does)")  # fmt: skip


def test_serve_port_on_the_plcs_port_is_refused_as_the_file_would_be(tmp_path: Path) -> None:
    plc = free_port()
    text = _set(_enabled(sim_toml(free_port()), "plc"), "plc", "port", str(plc))
    done = _serve(tmp_path, text, "--port", str(plc))
    assert done.returncode == 2, done.stderr
    assert f"with serve --port {plc}: 1 problem(s) in the configuration:" in done.stderr, done.stderr
    assert f"api.port and plc.port are both {plc} on one address" in _last(done), done.stderr
    assert "cellctl serving" not in done.stdout


def test_serve_host_empty_is_refused_as_the_file_would_be(tmp_path: Path) -> None:
    done = _serve(tmp_path, sim_toml(free_port()), "--host", "")
    assert done.returncode == 2, done.stderr
    assert "with serve --host '': 1 problem(s)" in done.stderr and "api.host: '' is not an address to listen on" in done.stderr


@contextmanager
def _unwritable(path: Path) -> Iterator[None]:
    """``path`` made unwritable for this process: chattr +i as root (root ignores modes), else no write bits."""
    if os.geteuid() == 0:
        if shutil.which("chattr") is None:
            pytest.skip("needs chattr as root")
        made = subprocess.run(["chattr", "+i", str(path)], capture_output=True, text=True)
        if made.returncode != 0:
            pytest.skip(f"chattr +i refused here: {made.stderr.strip()}")
        try:
            yield
        finally:
            subprocess.run(["chattr", "-i", str(path)], check=True)
    else:
        mode = path.stat().st_mode
        path.chmod(mode & ~0o222)
        try:
            yield
        finally:
            path.chmod(mode)


def _with_store(text: str, db: Path) -> str:
    assert text.count("[store.retention]") == 1
    return text.replace("[store.retention]", f'[store]\npath = "{db}"\n\n[store.retention]')


def test_a_store_folder_the_service_may_not_write_is_refused_by_check_and_serve(tmp_path: Path) -> None:
    folder = tmp_path / "store"
    folder.mkdir()
    db = folder / "cellctl.db"
    (tmp_path / "cell.toml").write_text(_with_store(sim_toml(free_port()), db), encoding="utf-8")
    why = f"[store] path {db}: the service's user may not write in {folder}; give it the right to, or {STORE_FIX}"
    with _unwritable(folder):
        if subprocess.run(["touch", str(folder / "probe")], capture_output=True).returncode == 0:
            pytest.skip("the OS lets this process write in the folder")  # the truth decides
        check = _check(tmp_path)
        done = _serve(tmp_path, (tmp_path / "cell.toml").read_text())
    assert check.returncode == 2 and f"  - {why}" in check.stderr.splitlines(), check.stdout + check.stderr
    assert done.returncode == 2, done.stderr
    assert _last(done) == f"error: {why}"


@pytest.mark.parametrize("which", ["lock", "database"])
def test_a_store_file_the_service_may_not_write_exits_2_naming_store_path(tmp_path: Path, which: str) -> None:
    db = tmp_path / "var" / "cellctl.db"
    db.parent.mkdir()
    target = db.with_name("cellctl.db.lock") if which == "lock" else db
    if which == "database":
        subprocess.run([sys.executable, "-c", f"from cellctl.store import CellStore; CellStore.open({str(db)!r}).close()"],
                       check=True)  # fmt: skip
    else:
        target.write_text("")
    with _unwritable(target):
        try:
            target.open("r+").close()
            pytest.skip("the OS lets this process write the file")  # the truth decides
        except PermissionError:
            pass
        done = _serve(tmp_path, _with_store(sim_toml(free_port()), db))
    assert done.returncode == 2, done.stderr
    if which == "lock":
        assert _last(done) == (f"error: [store] path {db}: its lock file {target} cannot be made or written (Operation "
                               f"not permitted); give the service's user the right to, or {STORE_FIX}")  # fmt: skip
    else:
        assert _last(done) == (f"error: [store] path {db}: the service's user may not read and write the file; give it the "
                               f"right to, or {STORE_FIX}")  # fmt: skip


def test_a_folder_at_store_path_exits_2(tmp_path: Path) -> None:
    folder = tmp_path / "afolder"
    folder.mkdir()
    done = _serve(tmp_path, _with_store(sim_toml(free_port()), folder))
    assert done.returncode == 2, done.stderr
    assert _last(done).startswith(f"error: [store] path {folder} is a folder; the store is one SQLite file"), done.stderr


def test_a_file_at_calibration_directory_exits_2(tmp_path: Path) -> None:
    (tmp_path / "afile").write_text("x")
    text = sim_toml(free_port()).replace('directory = "var/calibration"', f'directory = "{tmp_path / "afile"}"', 1)
    done = _serve(tmp_path, text)
    assert done.returncode == 2, done.stderr
    assert _last(done).startswith(f"error: calibration.directory {tmp_path / 'afile'}: the folder cannot be created"), done.stderr
    assert not (tmp_path / "var" / "cellctl.db").exists()  # refused before the store was made
