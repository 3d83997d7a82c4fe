"""Matrix bundle: everything the online reconstruction of one patch needs, on disk.

A bundle is a folder (docs/bundle.md)::

    <patch name>/
        manifest.json      schema version, patch, hashes, parameters, grids, array index
        <array>.npy        one NumPy file per array (loaded memory-mapped)

The manifest lists every array with shape, dtype and sha256. :func:`load_bundle` turns each
way a bundle can be broken into one specific :class:`BundleError` subclass, refuses schema
versions it does not know, and — given the layout the caller expects — refuses bundles of
another patch (:class:`BundleForeignError`) or built from other parameters
(:class:`BundleStaleError`). :func:`save_bundle` never writes into an existing bundle: it
writes a temporary sibling folder and renames it into place.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

FORMAT = "tactile_contact.bundle"
SCHEMA_VERSION = 2
MANIFEST = "manifest.json"


class BundleError(Exception):
    """Base class of every bundle problem; the message names the bundle path."""


class BundleNotFoundError(BundleError):
    """No bundle folder or no manifest at the given path."""


class BundleVersionError(BundleError):
    """The manifest's format or schema version is not one this library reads."""


class BundleCorruptError(BundleError):
    """Manifest unreadable, an array missing, truncated, of the wrong shape/dtype or checksum."""


class BundleForeignError(BundleError):
    """The bundle belongs to another patch than the one expected."""


class BundleStaleError(BundleError):
    """The bundle was built from other layout or parameters than the expected ones."""


@dataclass(frozen=True)
class Bundle:
    """A loaded bundle: ``manifest`` (dict) and ``arrays`` (name → read-only array)."""

    path: Path
    manifest: dict[str, Any]
    arrays: dict[str, NDArray[Any]]

    @property
    def patch(self) -> str:
        return str(self.manifest["patch"])

    @property
    def layout_hash(self) -> str:
        return str(self.manifest["layout_hash"])

    @property
    def parameter_hash(self) -> str:
        return str(self.manifest["parameter_hash"])

    def __getitem__(self, name: str) -> NDArray[Any]:
        return self.arrays[name]


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_bundle(
    path: str | Path, manifest: dict[str, Any], arrays: dict[str, NDArray[Any]]
) -> Path:
    """Write a bundle folder at ``path`` atomically (temporary folder, then rename).

    ``manifest`` must hold ``patch``, ``layout_hash`` and ``parameter_hash``; format, schema
    version and the array index are added here. An existing bundle at ``path`` is replaced only
    after the new one is complete.
    """
    dest = Path(path)
    for key in ("patch", "layout_hash", "parameter_hash"):
        if key not in manifest:
            raise ValueError(f"manifest needs key {key!r}")
    for name, arr in arrays.items():
        if not name.isidentifier():
            raise ValueError(f"array name {name!r} must be an identifier")
        a = np.asarray(arr)
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise ValueError(f"array {name!r} contains NaN or inf")
    dest.parent.mkdir(parents=True, exist_ok=True)
    # Not tempfile.mkdtemp: that makes the folder private (0700), and a bundle is read by
    # nodes that may run as other users. mkdir gives the umask's usual mode.
    tmp = dest.parent / f".{dest.name}.tmp-{uuid.uuid4().hex}"
    tmp.mkdir()
    try:
        index = {}
        for name, arr in arrays.items():
            a = np.ascontiguousarray(arr)
            f = tmp / f"{name}.npy"
            np.save(f, a, allow_pickle=False)
            index[name] = {
                "file": f.name,
                "shape": list(a.shape),
                "dtype": a.dtype.str,
                "sha256": _sha256(f),
            }
        full = {"format": FORMAT, "schema_version": SCHEMA_VERSION, **manifest, "arrays": index}
        (tmp / MANIFEST).write_text(json.dumps(full, indent=2, sort_keys=True, allow_nan=False))
        old = None
        if dest.exists():
            old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
            os.replace(dest, old)
        os.replace(tmp, dest)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest


def read_manifest(path: str | Path) -> dict[str, Any]:
    """The manifest of the bundle at ``path``, version-checked but arrays not opened."""
    p = Path(path)
    mf = p / MANIFEST
    if not p.is_dir():
        raise BundleNotFoundError(f"{p}: no bundle folder")
    if not mf.is_file():
        raise BundleNotFoundError(f"{p}: no {MANIFEST}")
    try:
        m = json.loads(mf.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BundleCorruptError(f"{p}: unreadable {MANIFEST}: {exc}") from None
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise BundleVersionError(
            f"{p}: not a {FORMAT} manifest (format {m.get('format')!r})"
            if isinstance(m, dict)
            else f"{p}: manifest is not a mapping"
        )
    ver = m.get("schema_version")
    if isinstance(ver, int) and not isinstance(ver, bool) and ver > SCHEMA_VERSION:
        made = m.get("library_version", "a newer version")
        raise BundleVersionError(
            f"{p}: bundle schema version {ver} was written by tactile_contact {made}, newer "
            f"than this one (it reads version {SCHEMA_VERSION}): update tactile_contact, or "
            "rebuild the bundle with this one"
        )
    if ver != SCHEMA_VERSION:
        raise BundleVersionError(
            f"{p}: bundle schema version {ver!r} is not supported "
            f"(this library reads version {SCHEMA_VERSION}); rebuild it"
        )
    for key in ("patch", "layout_hash", "parameter_hash", "arrays"):
        if key not in m:
            raise BundleCorruptError(f"{p}: manifest lacks key {key!r}")
    return m


def _since(m: dict[str, Any]) -> str:
    source = m.get("layout_source")
    return f"; built from {source}" if isinstance(source, str) else ""


def _source_patch(p: Path, m: dict[str, Any], loaded: Any = None) -> Any:
    """The patch of the layout file the bundle was built from, None if that file is gone (or
    was never recorded). Raises BundleStaleError if the file no longer loads or no longer
    holds the patch: the bundle cannot be trusted to match the skin it describes. ``loaded``:
    that file already loaded (a Layout, or the LayoutError loading it raised), else read."""
    from tactile_contact.model.layout import LayoutError, load_layout

    source = m.get("layout_source")
    if not isinstance(source, str) or not Path(source).is_file():
        return None
    try:
        if isinstance(loaded, Exception):
            raise LayoutError(str(loaded))
        layout = load_layout(source) if loaded is None else loaded
    except LayoutError as exc:
        raise BundleStaleError(
            f"{p}: its layout file no longer loads ({exc}); fix it or rebuild the bundle"
        ) from None
    try:
        return layout.patch(str(m["patch"]))
    except KeyError:
        raise BundleStaleError(
            f"{p}: its layout file {source} no longer has patch {m['patch']!r}; rebuild"
        ) from None


def _check_patch(p: Path, m: dict[str, Any], expected: Any) -> None:
    """Raise BundleForeignError / BundleStaleError unless the bundle (manifest ``m``) is of
    the patch ``expected`` and built from its layout and parameters."""
    if m["patch"] != expected.name:
        raise BundleForeignError(
            f"{p}: bundle of patch {m['patch']!r}, expected patch {expected.name!r}"
        )
    if m["layout_hash"] != expected.layout_hash():
        raise BundleStaleError(
            f"{p}: built for another module layout of patch "
            f"{m['patch']!r} (layout hash differs{_since(m)}); rebuild it"
        )
    if m["parameter_hash"] != expected.parameter_hash():
        raise BundleStaleError(
            f"{p}: built from other parameters of patch {m['patch']!r} "
            f"(parameter hash differs{_since(m)}); rebuild it"
        )


def layout_source(bundle: Bundle) -> Path | None:
    """The layout file the bundle was built from (``tactile-contact-build`` records it), or
    None where none was recorded."""
    source = bundle.manifest.get("layout_source")
    return Path(source) if isinstance(source, str) else None


def source_problem(path: str | Path, loaded: Any = None) -> str:
    """Why the bundle at ``path`` no longer matches the layout file it was built from — what
    :func:`load_bundle` would refuse it for — or "" (it matches, or that file is gone or was
    never recorded). Reads the manifest and the layout (unless ``loaded``: that file already
    loaded, or the LayoutError it raised), no array."""
    p = Path(path)
    try:
        m = read_manifest(p)
        expected = _source_patch(p, m, loaded)
        if expected is not None:
            _check_patch(p, m, expected)
    except BundleError as exc:
        return str(exc)
    return ""


def load_bundle(
    path: str | Path,
    expected_layout: Any = None,
    *,
    verify: bool = True,
    mmap: bool = True,
    check_source: bool = True,
) -> Bundle:
    """Open the bundle at ``path``.

    Args:
        expected_layout: a :class:`tactile_contact.model.layout.PatchLayout`; the bundle must be of
            that patch (else :class:`BundleForeignError`) and built from the same layout and
            parameters (else :class:`BundleStaleError`).
        verify: check every array's sha256 (reads each file once).
        mmap: memory-map the arrays (read-only) instead of reading them.
        check_source: without ``expected_layout``, compare the bundle with the layout file it
            was built from (``layout_source``, recorded by ``tactile-contact-build``) when that
            file still exists: a module moved or a parameter changed since the build makes it
            stale (:class:`BundleStaleError`).
    """
    p = Path(path)
    m = read_manifest(p)
    if expected_layout is None and check_source:
        expected_layout = _source_patch(p, m)
    if expected_layout is not None:
        _check_patch(p, m, expected_layout)
    arrays: dict[str, NDArray[Any]] = {}
    index = m["arrays"]
    if not isinstance(index, dict):
        raise BundleCorruptError(f"{p}: manifest 'arrays' is not a mapping")
    lacking = [name for name in REQUIRED_ARRAYS if name not in index]
    if lacking:
        # (a Reconstructor met it as a bare KeyError)
        raise BundleCorruptError(f"{p}: manifest lists no array {', '.join(map(repr, lacking))}")
    for name, info in index.items():
        try:
            f = p / str(info["file"])
            shape, dtype, sha = tuple(info["shape"]), np.dtype(info["dtype"]), info["sha256"]
        except (KeyError, TypeError) as exc:
            raise BundleCorruptError(f"{p}: bad manifest entry for array {name!r}: {exc}") from None
        if not f.is_file() or f.parent != p:
            raise BundleCorruptError(f"{p}: array {name!r} missing ({f.name})")
        if verify and _sha256(f) != sha:
            raise BundleCorruptError(
                f"{p}: array {name!r} ({f.name}) fails its sha256 check (truncated or modified)"
            )
        try:
            a = np.load(f, mmap_mode="r" if mmap else None, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise BundleCorruptError(f"{p}: array {name!r} ({f.name}) unreadable: {exc}") from None
        if a.shape != shape or a.dtype != dtype:
            raise BundleCorruptError(
                f"{p}: array {name!r} is {a.dtype} {a.shape}, manifest says {dtype} {shape}"
            )
        arrays[name] = a
    _check_shapes(p, arrays)
    return Bundle(p, m, arrays)


#: Arrays every bundle holds (tactile_contact.offline.build writes them).
REQUIRED_ARRAYS = ("taxel_xy", "taxel_ids", "forward", "inverse", "deflection_operator")


def _check_shapes(p: Path, arrays: dict[str, NDArray[Any]]) -> None:
    """The arrays' shapes against each other (K taxels, N traction cells): a manifest that
    agrees with each file can still pair files of different patches or builds."""
    k, n = arrays["taxel_xy"].shape[0], arrays["forward"].shape[-1]
    # (in this order: forward is known 2-D before n is compared with another array)
    expect = {
        "taxel_xy": (k, 2),
        "taxel_ids": (k,),
        "forward": (k, None),
        "inverse": (n, k),
        "deflection_operator": (None, n),
    }
    for name, want in expect.items():
        got = arrays[name].shape
        same = len(got) == len(want) and all(
            w is None or g == w for g, w in zip(got, want, strict=True)
        )
        if not same:
            shown = tuple("·" if w is None else w for w in want)
            raise BundleCorruptError(
                f"{p}: array {name!r} has shape {got}, the others want {shown} "
                f"({k} taxels): arrays of different builds or patches?"
            )


def replacing(path: str | Path, source: str | Path, reason: str, force: bool = False) -> str:
    """Why the bundle at ``path`` is replaced by a build from the layout file ``source``
    (``reason``: :func:`bundle_status`'s). Without ``force`` a BundleError refuses what a
    rebuild would lose: a bundle made by a newer library (this one cannot read it, nor tell
    what it holds), and a calibrated bundle (tactile-contact-calibrate: its manifest keeps the
    fit, its uncertainties and report, which a build does not make)."""
    p = Path(path)
    try:
        m = json.loads((p / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return reason
    if not isinstance(m, dict) or force:
        return reason
    ver = m.get("schema_version")
    if isinstance(ver, int) and ver > SCHEMA_VERSION:
        made = m.get("library_version", "a newer version")
        raise BundleVersionError(
            f"{p}: made by tactile_contact {made} (bundle schema {ver}; this library writes "
            f"{SCHEMA_VERSION}): not replaced — build with that version, or pass --force"
        )
    if isinstance(m.get("calibration"), dict):
        was = m.get("layout_source", "its calibrated layout")
        same = isinstance(was, str) and Path(was).resolve() == Path(source).resolve()
        hint = (
            "run tactile-contact-calibrate again"
            if same
            else f"build from {was} instead (tactile-contact-calibrate wrote it)"
        )
        raise BundleError(
            f"{p}: a calibrated bundle (its manifest keeps the calibration); building from "
            f"{source} would replace it with an uncalibrated one: {hint}, or pass --force "
            f"(it is not up to date: {reason})"
        )
    return reason


def bundle_status(path: str | Path, layout: Any) -> str:
    """``"missing"``, ``"up-to-date"`` or why it must be rebuilt (for the build tool)."""
    return bundle_check(path, layout)[0]


def bundle_check(path: str | Path, layout: Any) -> tuple[str, str]:
    """(:func:`bundle_status`, the loader's message why the bundle does not load for
    ``layout``: "" when it does)."""
    try:
        load_bundle(path, layout, verify=True)
    except BundleNotFoundError as exc:
        return "missing", str(exc)
    except BundleError as exc:
        return f"rebuild: {type(exc).__name__}", str(exc)
    return "up-to-date", ""
