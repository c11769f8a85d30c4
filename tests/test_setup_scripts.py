"""scripts/vulkan.sh (the Vulkan part of `make setup`) on made-up systems: Debian 12 with one-line
and deb822 apt sources, Ubuntu 22.04 and 24.04, a system without apt, with and without root.

Each case gets its own /etc (GAUSSTAC_ETC) and a PATH holding only stand-ins for apt-get, sudo,
id and dpkg-query (they log their arguments) next to the real awk, sed and tee. The stand-in
for SAPIEN's Python succeeds once the stand-in apt-get has "installed" a working Mesa. What
these tests guard: the script picks the machine's own Debian mirror, writes a backports line
only on Debian bookworm, never writes apt sources elsewhere, and prints the exact commands
when it cannot install. They do not run apt on a real Ubuntu.
"""
import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "vulkan.sh"

DEBIAN = 'PRETTY_NAME="Debian GNU/Linux 12 (bookworm)"\nID=debian\nVERSION_ID="12"\nVERSION_CODENAME=bookworm\n'
UBUNTU_2404 = 'PRETTY_NAME="Ubuntu 24.04.1 LTS"\nID=ubuntu\nID_LIKE=debian\nVERSION_CODENAME=noble\n'
UBUNTU_2204 = 'PRETTY_NAME="Ubuntu 22.04.4 LTS"\nID=ubuntu\nID_LIKE=debian\nVERSION_CODENAME=jammy\n'
FEDORA = 'PRETTY_NAME="Fedora Linux 40"\nID=fedora\nVERSION_ID=40\n'

ONE_LINE = ("deb http://mirror.example.org/debian bookworm main\n"
            "# deb http://commented.example.org/debian bookworm main\n"
            "deb [arch=amd64] http://security.debian.org/debian-security bookworm-security main\n")
DEB822 = ("Types: deb\nURIs: http://deb822.example.org/debian\nSuites: bookworm bookworm-updates\n"
          "Components: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n\n"
          "Types: deb\nURIs: http://deb.debian.org/debian-security\nSuites: bookworm-security\nComponents: main\n")
DEB822_BACKPORTS = DEB822.replace("Suites: bookworm bookworm-updates", "Suites: bookworm bookworm-backports")
UBUNTU_SOURCES = ("Types: deb\nURIs: http://archive.ubuntu.com/ubuntu/\nSuites: noble noble-updates\n"
                  "Components: main universe\n")

STUB = """#!/bin/bash
echo "{name} $*" >> "{log}"
{body}
"""


def make_system(tmp_path, os_release, sources=None, deb822=None, root=True, sudo=True, apt=True,
                mesa_works=True, vulkan_now=False):
    """A made-up machine: returns (env, etc, log)."""
    etc, bin_, log = tmp_path / "etc", tmp_path / "bin", tmp_path / "calls.log"
    (etc / "apt" / "sources.list.d").mkdir(parents=True)
    bin_.mkdir()
    log.write_text("")
    (etc / "os-release").write_text(os_release)
    if sources is not None:
        (etc / "apt" / "sources.list").write_text(sources)
    for name, text in (deb822 or {}).items():
        (etc / "apt" / "sources.list.d" / name).write_text(text)
    marker = tmp_path / "mesa-installed"
    if vulkan_now:
        marker.write_text("")

    def stub(name, body=""):
        path = bin_ / name
        path.write_text(STUB.format(name=name, log=log, body=body))
        path.chmod(path.stat().st_mode | stat.S_IEXEC)

    stub("id", f'echo {0 if root else 1000}')
    stub("dpkg-query", "echo 23.2.1-1ubuntu3.1~22.04.3")
    if sudo:
        stub("sudo", 'exec "$@"')
    if apt:
        install = f'touch "{marker}"' if mesa_works else ":"
        stub("apt-get", f'if [[ " $* " == *" install "* ]]; then {install}; fi; exit 0')
    python = bin_ / "sapien-python"  # SAPIEN makes a render system once Mesa is "installed"
    python.write_text(f'#!/bin/bash\ncat > /dev/null\n[ -e "{marker}" ]\n')
    python.chmod(0o755)
    for tool in ("awk", "sed", "tee", "cat", "touch"):
        os.symlink(shutil.which(tool), bin_ / tool)
    env = {"PATH": str(bin_), "GAUSSTAC_ETC": str(etc), "HOME": str(tmp_path)}
    return env, etc, log, python


def run(env, python):
    bash = shutil.which("bash")
    out = subprocess.run([bash, str(SCRIPT), str(python)], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out


def apt_calls(log):
    return [line.split(" ", 1)[1] for line in log.read_text().splitlines() if line.startswith("apt-get ")]


def tree(etc):
    return sorted((str(p.relative_to(etc)), p.read_text() if p.is_file() else None) for p in etc.rglob("*"))


@pytest.fixture(autouse=True)
def _bash():
    if shutil.which("bash") is None or shutil.which("awk") is None:
        pytest.skip("needs bash and awk")


def test_a_working_vulkan_device_changes_nothing(tmp_path):
    env, etc, log, py = make_system(tmp_path, DEBIAN, ONE_LINE, vulkan_now=True)
    before = tree(etc)
    out = run(env, py)
    assert "Vulkan device found" in out.stdout
    assert apt_calls(log) == [] and tree(etc) == before


@pytest.mark.parametrize("sources, deb822, mirror", [
    (ONE_LINE, None, "http://mirror.example.org/debian"),
    (None, {"debian.sources": DEB822}, "http://deb822.example.org/debian"),
], ids=["one-line", "deb822"])
def test_debian_12_gets_backports_on_its_own_mirror(tmp_path, sources, deb822, mirror):
    env, etc, log, py = make_system(tmp_path, DEBIAN, sources, deb822)
    out = run(env, py)
    added = etc / "apt" / "sources.list.d" / "bookworm-backports.list"
    assert added.read_text() == f"deb {mirror} bookworm-backports main\n"
    assert apt_calls(log) == ["update -qq", "install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1"]
    assert "SAPIEN renders on the CPU" in out.stdout


def test_debian_12_with_backports_already_listed_adds_no_line(tmp_path):
    env, etc, log, py = make_system(tmp_path, DEBIAN, deb822={"debian.sources": DEB822_BACKPORTS})
    before = tree(etc)
    run(env, py)
    assert tree(etc) == before
    assert apt_calls(log)[-1] == "install -y -qq -t bookworm-backports mesa-vulkan-drivers libvulkan1"


def test_debian_12_without_root_prints_the_commands_and_writes_nothing(tmp_path):
    env, etc, log, py = make_system(tmp_path, DEBIAN, ONE_LINE, root=False, sudo=False)
    before = tree(etc)
    out = run(env, py)
    assert tree(etc) == before and apt_calls(log) == []
    assert ("echo 'deb http://mirror.example.org/debian bookworm-backports main' | sudo tee "
            "/etc/apt/sources.list.d/bookworm-backports.list") in out.stderr
    assert "apt-get install -t bookworm-backports mesa-vulkan-drivers libvulkan1" in out.stderr


@pytest.mark.parametrize("os_release, deb822", [(UBUNTU_2404, {"ubuntu.sources": UBUNTU_SOURCES}),
                                                (UBUNTU_2204, None)], ids=["24.04", "22.04"])
def test_ubuntu_takes_its_own_mesa_and_no_foreign_suite(tmp_path, os_release, deb822):
    sources = None if deb822 else "deb http://archive.ubuntu.com/ubuntu jammy main universe\n"
    env, etc, log, py = make_system(tmp_path, os_release, sources, deb822, root=False)  # through sudo
    before = tree(etc)
    out = run(env, py)
    assert tree(etc) == before
    assert apt_calls(log) == ["update -qq", "install -y -qq mesa-vulkan-drivers libvulkan1"]
    assert "sudo apt-get" in log.read_text()
    assert "SAPIEN renders on the CPU" in out.stdout


def test_an_old_mesa_is_named_with_what_to_install(tmp_path):
    env, etc, log, py = make_system(tmp_path, UBUNTU_2204, "deb http://archive.ubuntu.com/ubuntu jammy main\n",
                                    mesa_works=False)
    before = tree(etc)
    out = run(env, py)
    assert tree(etc) == before
    assert "SAPIEN-based tests will be skipped" in out.stderr
    assert "installed here: 23.2.1-1ubuntu3.1~22.04.3" in out.stderr


def test_a_system_without_apt_is_told_what_to_install(tmp_path):
    env, etc, log, py = make_system(tmp_path, FEDORA, apt=False)
    out = run(env, py)
    assert apt_calls(log) == []
    assert "Mesa Vulkan drivers (lavapipe, Mesa >= 25)" in out.stderr
