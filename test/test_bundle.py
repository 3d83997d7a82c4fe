"""Matrix bundles: a valid fixture, then one thing broken at a time."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.model.layout import load_layout, parse_layout
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import (
    SCHEMA_VERSION,
    BundleCorruptError,
    BundleError,
    BundleForeignError,
    BundleNotFoundError,
    BundleStaleError,
    BundleVersionError,
    bundle_status,
    load_bundle,
    save_bundle,
)

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    patch = load_layout(LAYOUT).patches[0]
    manifest, arrays = build_patch(patch)
    return save_bundle(tmp_path_factory.mktemp("bundles") / patch.name, manifest, arrays)


@pytest.fixture
def bundle(built, tmp_path) -> Path:
    dest = tmp_path / "hexagon"
    shutil.copytree(built, dest)
    return dest


@pytest.fixture(scope="module")
def patch():
    return load_layout(LAYOUT).patches[0]


def _manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def _write(path: Path, m: dict) -> None:
    (path / "manifest.json").write_text(json.dumps(m))


def test_valid_bundle_loads_memory_mapped(bundle, patch):
    b = load_bundle(bundle, patch)
    assert b.patch == "hexagon" and b.manifest["schema_version"] == SCHEMA_VERSION
    assert isinstance(b["forward"], np.memmap)
    assert b["forward"].shape[0] == 72 and b["forward"].dtype == np.float64
    assert b["inverse"].dtype == np.float32
    np.testing.assert_array_equal(b["taxel_xy"], patch.taxel_xy())
    assert bundle_status(bundle, patch) == "up-to-date"
    assert not isinstance(load_bundle(bundle, mmap=False)["forward"], np.memmap)
    ny, nx = b.manifest["traction_grid"]["shape"]
    assert b["forward"].shape[1] == int(np.asarray(b["traction_grid_mask"]).sum()) <= ny * nx


def test_missing_folder_and_manifest(tmp_path):
    with pytest.raises(BundleNotFoundError, match="no bundle folder"):
        load_bundle(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BundleNotFoundError, match=r"no manifest\.json"):
        load_bundle(tmp_path / "empty")
    assert bundle_status(tmp_path / "nope", None) == "missing"


def test_stale_parameters_refused(bundle):
    doc = yaml.safe_load(LAYOUT.read_text())
    doc["patches"][0]["elastomer"]["young"] = 1.77e5
    other = parse_layout(doc).patches[0]
    with pytest.raises(BundleStaleError, match="parameter hash differs"):
        load_bundle(bundle, other)
    assert bundle_status(bundle, other) == "rebuild: BundleStaleError"


def test_stale_geometry_refused(bundle):
    doc = yaml.safe_load(LAYOUT.read_text())
    doc["patches"][0]["modules"][0]["rotation_deg"] = 0
    with pytest.raises(BundleStaleError, match="layout hash differs"):
        load_bundle(bundle, parse_layout(doc).patches[0])


def test_foreign_patch_refused(bundle):
    doc = yaml.safe_load(LAYOUT.read_text())
    doc["patches"][0]["name"] = "palm"
    with pytest.raises(
        BundleForeignError, match="bundle of patch 'hexagon', expected patch 'palm'"
    ):
        load_bundle(bundle, parse_layout(doc).patches[0])


@pytest.mark.parametrize(
    "version", [SCHEMA_VERSION - 1, SCHEMA_VERSION + 1, str(SCHEMA_VERSION), None]
)
def test_unknown_version_refused(bundle, version):
    # The previous version too: its deflection operator and round tables were Love's for a
    # boussinesq patch (docs/bundle.md).
    m = _manifest(bundle)
    m["schema_version"] = version
    _write(bundle, m)
    newer = "newer than this one.*update tactile_contact" if version == SCHEMA_VERSION + 1 else ""
    with pytest.raises(BundleVersionError, match=f"schema version.*{newer}"):
        load_bundle(bundle)


def test_wrong_format_refused(bundle):
    m = _manifest(bundle)
    m["format"] = "something.else"
    _write(bundle, m)
    with pytest.raises(BundleVersionError, match=r"not a tactile_contact\.bundle manifest"):
        load_bundle(bundle)


def test_unreadable_manifest(bundle):
    (bundle / "manifest.json").write_text("{not json")
    with pytest.raises(BundleCorruptError, match=r"unreadable manifest\.json"):
        load_bundle(bundle)


def test_missing_array(bundle):
    (bundle / "inverse.npy").unlink()
    with pytest.raises(BundleCorruptError, match="array 'inverse' missing"):
        load_bundle(bundle)


def test_an_array_the_manifest_does_not_list(bundle):
    """A manifest without 'inverse' loaded; the Reconstructor then met a bare KeyError."""
    m = _manifest(bundle)
    del m["arrays"]["inverse"]
    _write(bundle, m)
    with pytest.raises(BundleCorruptError, match="manifest lists no array 'inverse'"):
        load_bundle(bundle)


def test_arrays_of_different_patches_are_refused_by_their_shapes(bundle):
    """Each file agreeing with its manifest entry is not enough: the taxel positions of a
    patch with a taxel fewer (a file of another build, the manifest rewritten to match)."""
    xy = np.load(bundle / "taxel_xy.npy")[:-1]
    np.save(bundle / "taxel_xy.npy", xy)
    m = _manifest(bundle)
    m["arrays"]["taxel_xy"]["shape"] = list(xy.shape)
    _write(bundle, m)
    with pytest.raises(BundleCorruptError, match=r"array 'taxel_ids' has shape \(72,\)"):
        load_bundle(bundle, verify=False)


def test_truncated_array(bundle):
    f = bundle / "forward.npy"
    f.write_bytes(f.read_bytes()[:-100])
    with pytest.raises(BundleCorruptError, match=r"'forward'.*sha256"):
        load_bundle(bundle)
    with pytest.raises(BundleCorruptError, match=r"'forward'.*unreadable"):
        load_bundle(bundle, verify=False)


def test_modified_array(bundle):
    a = np.load(bundle / "forward.npy")
    a[0, 0] += 1e-12
    np.save(bundle / "forward.npy", a)
    with pytest.raises(BundleCorruptError, match="sha256"):
        load_bundle(bundle)


@pytest.mark.parametrize(
    ("key", "value", "what"), [("shape", [1, 2], "shape"), ("dtype", "<f4", "dtype")]
)
def test_wrong_shape_or_dtype(bundle, key, value, what):
    m = _manifest(bundle)
    m["arrays"]["forward"][key] = value
    _write(bundle, m)
    with pytest.raises(BundleCorruptError, match="array 'forward' is float64"):
        load_bundle(bundle)


def test_manifest_missing_key(bundle):
    m = _manifest(bundle)
    del m["parameter_hash"]
    _write(bundle, m)
    with pytest.raises(BundleCorruptError, match="lacks key 'parameter_hash'"):
        load_bundle(bundle)


def test_all_errors_share_the_base_class():
    for cls in (
        BundleNotFoundError,
        BundleVersionError,
        BundleCorruptError,
        BundleForeignError,
        BundleStaleError,
    ):
        assert issubclass(cls, BundleError)


def test_save_replaces_atomically_and_rejects_nan(tmp_path):
    m = {"patch": "p", "layout_hash": "a", "parameter_hash": "b"}
    save_bundle(tmp_path / "p", m, {"x": np.arange(3.0)})
    save_bundle(tmp_path / "p", m, {"y": np.ones(2)})
    assert sorted(f.name for f in (tmp_path / "p").iterdir()) == ["manifest.json", "y.npy"]
    assert [f.name for f in tmp_path.iterdir()] == ["p"]  # no temporary folder left behind
    # Readable by other users as any folder made under the umask is (not mkdtemp's 0700).
    (tmp_path / "probe").mkdir()
    assert (tmp_path / "p").stat().st_mode & 0o777 == (tmp_path / "probe").stat().st_mode & 0o777
    (tmp_path / "probe").rmdir()
    with pytest.raises(ValueError, match="NaN"):
        save_bundle(tmp_path / "q", m, {"x": np.array([np.nan])})
    assert not (tmp_path / "q").exists() and [f.name for f in tmp_path.iterdir()] == ["p"]
    with pytest.raises(ValueError, match="needs key 'patch'"):
        save_bundle(tmp_path / "r", {}, {})


@pytest.mark.parametrize("key", ["params", "traction_grid", "deflection_grid"])
def test_a_manifest_edited_by_hand_is_a_bundle_error_naming_it(bundle, key):
    """A manifest key removed by hand passed the loader and ended in a bare KeyError in the
    reconstructor: a BundleCorruptError naming the bundle and the key."""
    from tactile_contact.inverse.reconstruction import Reconstructor

    m = _manifest(bundle)
    assert key in m
    del m[key]
    _write(bundle, m)
    with pytest.raises(BundleCorruptError, match=rf"{bundle}: .*missing key '{key}'"):
        Reconstructor.from_bundle(bundle)
