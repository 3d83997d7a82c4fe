"""Old flat module paths (before the stage packages) still import, as the same module objects,
with a DeprecationWarning naming the new place; names that never existed still fail."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

from tactile_contact import _moved


@pytest.mark.parametrize("old", sorted(_moved.MOVED))
def test_every_old_module_is_the_new_one(old: str) -> None:
    new = _moved.new_name(f"tactile_contact.{old}")
    assert new is not None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sys.modules.pop(f"tactile_contact.{old}", None)
        module = importlib.import_module(f"tactile_contact.{old}")
    assert module is importlib.import_module(new)
    assert module.__spec__.name == new  # the module keeps its own spec
    assert any(new in str(w.message) and w.category is DeprecationWarning for w in caught)


def test_submodule_of_a_moved_package_is_not_loaded_twice() -> None:
    import tactile_contact.elastic.love as old
    import tactile_contact.model.elastic.love as new

    assert old is new
    from tactile_contact.elastic import love_matrix
    from tactile_contact.model.elastic import love_matrix as new_love_matrix

    assert love_matrix is new_love_matrix


def test_from_package_import_old_module() -> None:
    from tactile_contact import codec
    from tactile_contact.canbus import codec as new_codec

    assert codec is new_codec


def test_unknown_names_still_fail() -> None:
    with pytest.raises(ModuleNotFoundError, match=r"tactile_contact\.no_such_module"):
        importlib.import_module("tactile_contact.no_such_module")
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("tactile_contact.elastic.no_such_module")


def test_python_dash_m_old_path_runs_the_new_module() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "tactile_contact.build", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    assert "usage: tactile-contact-build" in out.stdout


def test_public_api_names() -> None:
    import tactile_contact
    from tactile_contact import Contact, ContactResult, Reconstructor
    from tactile_contact.inverse.reconstruction import Reconstructor as New

    assert Reconstructor is New
    assert ContactResult.__name__ == "ContactResult" and Contact.__name__ == "Contact"
    with pytest.raises(AttributeError):
        tactile_contact.NoSuchThing  # noqa: B018


def test_file_formats_keep_their_names() -> None:
    """The on-disk format names are the files', not the modules': bundles built before the
    move (manifest format "tactile_contact.bundle") still load."""
    from tactile_contact.offline import bundle

    assert bundle.FORMAT == "tactile_contact.bundle"


def test_names_of_the_split_reconstruction_module_still_resolve() -> None:
    """Constants and helpers that tactile_contact.reconstruction held before its stages got
    modules of their own resolve from there, with a warning naming the new module."""
    from tactile_contact.inverse import contact_fit, grid_fallback, reconstruction

    with pytest.warns(DeprecationWarning, match="grid_fallback"):
        assert reconstruction.SOLVER_CACHE_SIZE == grid_fallback.SOLVER_CACHE_SIZE
    with pytest.warns(DeprecationWarning, match="contact_fit"):
        assert reconstruction.FOLLOW_FRAMES == contact_fit.FOLLOW_FRAMES
    with pytest.raises(AttributeError, match="no_such_name"):
        reconstruction.no_such_name  # noqa: B018
