"""DAQP's C sources for a generated step: from the ``daqp`` sdist, fetched once and cached.

The project keeps no copy of DAQP's sources. ``czmpc codegen`` with ``solver = "daqp"``
takes them from the source distribution of the *installed* ``daqp`` version (the Python
controller's solver), which carries them under ``csrc/``: downloaded from the address
PyPI's JSON metadata gives and checked against its sha256 (with pip where an index has
no JSON API), unpacked into a
cache keyed by version (`cache_dir`: ``$XDG_CACHE_HOME/czmpc/daqp-VERSION``, else
``~/.cache/czmpc/daqp-VERSION``). Offline: download the sdist elsewhere
(``pip download daqp==VERSION --no-binary :all: --no-deps``) and give its path as
``daqp_sdist`` to `czmpc.codegen.generate_step`, or in the environment variable
`SDIST_ENV`.

Not with pip first: pip reads a sdist's metadata before it saves it, and with an empty
pip cache it first fetches daqp's build requirements (setuptools, Cython); measured here,
that had not finished after 300 s, against about a second for the direct download. The
sdist is fetched once per daqp version.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.parse
import urllib.request
from importlib import metadata
from pathlib import Path

from czmpc.codegen.errors import CodegenError

#: Environment variable naming a downloaded ``daqp-VERSION.tar.gz`` (offline generation).
SDIST_ENV = "CZMPC_DAQP_SDIST"
#: PyPI's JSON metadata of the project (``releases``: sha256 of every release's files; the
#: per-version address answered 404 for daqp 0.11.0 when measured).
PYPI_JSON = "https://pypi.org/pypi/daqp/json"
#: Seconds to wait for PyPI.
TIMEOUT_S = 60.0


def daqp_version() -> str:
    """The installed ``daqp`` version (the Python controller's DAQP).

    Raises
    ------
    CodegenError
        If ``daqp`` is not installed.
    """
    try:
        return metadata.version("daqp")
    except metadata.PackageNotFoundError as exc:
        raise CodegenError("codegen: solver = 'daqp' needs the package daqp (the Python "
                           "controller's solver); it is not installed: pip install "
                           "'czmpc[daqp]'") from exc


def cache_dir(version: str) -> Path:
    """Where the unpacked sources of ``daqp`` ``version`` are kept."""
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "czmpc" / f"daqp-{version}"


def _offline_hint(version: str) -> str:
    return (f"offline: run 'pip download daqp=={version} --no-binary :all: --no-deps' where "
            f"PyPI is reachable and give the file with {SDIST_ENV}=PATH (or "
            f"generate_step(..., daqp_sdist=PATH))")


def _pypi_sdist(version: str) -> tuple[str, str] | None:
    """The address and sha256 of ``daqp`` ``version``'s sdist from PyPI's JSON metadata, or
    None if that cannot be read (an index mirror without the JSON API)."""
    try:
        with urllib.request.urlopen(PYPI_JSON, timeout=TIMEOUT_S) as response:  # noqa: S310 - https constant
            info = json.load(response)
    except (OSError, ValueError):
        return None
    for entry in info.get("releases", {}).get(version, []):
        if entry.get("packagetype") == "sdist":
            # The address may be relative to the JSON's (a proxy of PyPI).
            return (urllib.parse.urljoin(PYPI_JSON, str(entry["url"])),
                    str(entry["digests"]["sha256"]))
    raise CodegenError(f"codegen: PyPI lists no sdist for daqp {version}; {_offline_hint(version)}")


def download_sdist(version: str, directory: Path) -> Path:
    """Download the sdist of ``daqp`` ``version`` into ``directory`` and check its sha256.

    From the address PyPI's JSON metadata gives, checked against its sha256 (seconds; pip
    would first build daqp's metadata, fetching setuptools and Cython: minutes with an
    empty pip cache). Where the JSON API cannot be read, with pip (which checks the hash
    the index lists).

    Raises
    ------
    CodegenError
        No network (the message says what to do offline), or a hash that differs.
    """
    found = _pypi_sdist(version)
    if found is not None:
        url, want = found
        sdist = directory / f"daqp-{version}.tar.gz"
        try:
            with urllib.request.urlopen(url, timeout=TIMEOUT_S) as response:  # noqa: S310 - PyPI's address
                sdist.write_bytes(response.read())
        except OSError as exc:
            raise CodegenError(f"codegen: could not download {url}: {exc}; "
                               f"{_offline_hint(version)}") from exc
        got = hashlib.sha256(sdist.read_bytes()).hexdigest()
        if got != want:
            raise CodegenError(f"codegen: {sdist.name} must have PyPI's sha256 {want}; got {got}")
        return sdist
    cmd = [sys.executable, "-m", "pip", "download", f"daqp=={version}", "--no-binary", ":all:",
           "--no-deps", "--disable-pip-version-check", "-d", str(directory)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    downloaded = sorted(directory.glob(f"daqp-{version}.tar.gz"))
    if done.returncode != 0 or not downloaded:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise CodegenError(f"codegen: pip must download the sdist of daqp {version}; got exit "
                           f"{done.returncode}: {' | '.join(tail)}; {_offline_hint(version)}")
    return downloaded[0]


def unpack_sdist(sdist: Path, version: str, target: Path) -> Path:
    """Unpack ``csrc/`` and ``LICENSE`` of ``sdist`` into ``target`` (replaced).

    Raises
    ------
    CodegenError
        If the file is not the sdist of ``daqp`` ``version`` with its C sources.
    """
    top = f"daqp-{version}/"
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        with tarfile.open(sdist, "r:gz") as tar:
            members = [m for m in tar.getmembers()
                       if m.isfile() and (m.name.startswith(top + "csrc/")
                                          or m.name == top + "LICENSE")]
            if not any(m.name.endswith("csrc/src/daqp.c") for m in members):
                raise CodegenError(f"codegen: {sdist} must be the sdist of daqp {version} (with "
                                   f"{top}csrc/src/daqp.c); got none")
            tmp = Path(tempfile.mkdtemp(prefix="daqp-", dir=target.parent))
            for member in members:
                dest = tmp / member.name[len(top):]
                dest.parent.mkdir(parents=True, exist_ok=True)
                source = tar.extractfile(member)
                if source is None:  # pragma: no cover - regular files only
                    continue
                dest.write_bytes(source.read())
    except (OSError, tarfile.TarError) as exc:
        raise CodegenError(f"codegen: {sdist} must be a readable daqp sdist; got {exc}") from exc
    if target.exists():
        shutil.rmtree(target)
    tmp.rename(target)
    return target


def daqp_sources(sdist: str | Path | None = None) -> Path:
    """A directory with DAQP's ``csrc/`` (``include``, ``src``) and ``LICENSE``, for the installed version.

    Parameters
    ----------
    sdist :
        A downloaded ``daqp-VERSION.tar.gz`` (offline); None: `SDIST_ENV` if set, else
        the cache, else a download with pip.

    Raises
    ------
    CodegenError
        As `download_sdist` and `unpack_sdist`.
    """
    version = daqp_version()
    target = cache_dir(version)
    given = sdist if sdist is not None else os.environ.get(SDIST_ENV)
    if given:
        return unpack_sdist(Path(given), version, target.parent / f"daqp-{version}-given")
    if (target / "csrc" / "src" / "daqp.c").is_file() and (target / "LICENSE").is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        return unpack_sdist(download_sdist(version, Path(tmp)), version, target)


def copy_daqp(out_dir: Path, sdist: str | Path | None = None) -> list[str]:
    """Copy DAQP's C sources and licence into ``out_dir/daqp``; return the source stems.

    Raises
    ------
    CodegenError
        As `daqp_sources`.
    """
    source = daqp_sources(sdist)
    dest = out_dir / "daqp"
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(source / "csrc" / "include", dest / "include")
    shutil.copytree(source / "csrc" / "src", dest / "src",
                    ignore=shutil.ignore_patterns("CMakeLists.txt"))
    (dest / "include" / "CMakeLists.txt").unlink(missing_ok=True)
    shutil.copyfile(source / "LICENSE", dest / "LICENSE")
    return sorted(p.stem for p in (dest / "src").glob("*.c"))


__all__ = ["SDIST_ENV", "cache_dir", "copy_daqp", "daqp_sources", "daqp_version",
           "download_sdist", "unpack_sdist"]
