"""Every delete removes only what pokeworld wrote: single files through io.remove_own_file (regular files only,
never a link's target), folders through an OwnedDir spec checked before anything is removed."""

import os

import pytest

from pokeworld.errors import ConfigError
from pokeworld.io import check_owned_dir, foreign_entries, record_owned, remove_own_file, staging_path
from pokeworld.real.rh20t.cache import SCENE_CACHE
from pokeworld.real.synthetic import SYNTHETIC_CFG_DIR, SYNTHETIC_TRUTH


def test_remove_own_file_deletes_regular_files_only(tmp_path):
    mine = tmp_path / "scissors.png"
    mine.write_bytes(b"png")
    record_owned(mine)  # as every pokeworld writer does
    remove_own_file(mine)
    assert not mine.exists()
    remove_own_file(mine)  # already gone: nothing to do
    target = tmp_path / "thesis.tex"
    target.write_text("years of work")
    link = tmp_path / "link.png"
    link.symlink_to(target)
    with pytest.raises(ConfigError, match="symbolic link"):
        remove_own_file(link)
    assert target.read_text() == "years of work" and link.is_symlink()
    (tmp_path / "folder").mkdir()
    with pytest.raises(ConfigError, match="folder"):
        remove_own_file(tmp_path / "folder")
    # a regular file pokeworld never recorded writing (a user's) is refused, and stays
    with pytest.raises(ConfigError, match="was not written by pokeworld"):
        remove_own_file(target)
    assert target.read_text() == "years of work"
    staging = staging_path(tmp_path / "corpus.h5")  # a staging copy of ours is recognised by its name
    staging.write_bytes(b"partial")
    remove_own_file(staging)
    assert not staging.exists()


def _tree(root, files):
    for f in files:
        p = root / f
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")


def test_a_synthetic_corpus_is_ours_and_a_user_file_inside_it_is_not(tmp_path):
    scene = "task_0001_user_0002_scene_0003_cfg_0007"
    cfg_dir, truth = tmp_path / "RH20T_cfg7", tmp_path / "truth"
    _tree(cfg_dir, ["calib/1650000000000/extrinsics.npy", "calib/1650000000000/intrinsics.npy",
                    "calib/1650000000000/tcp.npy", f"{scene}/metadata.json", f"{scene}/transformed/joint.npy",
                    f"{scene}/cam_036422060909/color.mp4", f"{scene}/cam_036422060909/timestamps.npy",
                    f"{scene}/cam_104122063678/color/1650000000000.jpg"])
    _tree(truth, ["manifest.json", f"{scene}.npz"])
    assert foreign_entries(cfg_dir, SYNTHETIC_CFG_DIR) == [] and foreign_entries(truth, SYNTHETIC_TRUTH) == []
    _tree(cfg_dir, [f"{scene}/notes.txt"])  # something a user put there: the folder is no longer only ours
    with pytest.raises(ConfigError, match="did not write"):
        check_owned_dir(cfg_dir, SYNTHETIC_CFG_DIR)
    os.symlink(tmp_path / "elsewhere", truth / f"{scene}_x.npz")  # a link is never ours either
    assert foreign_entries(truth, SYNTHETIC_TRUTH) == [f"{scene}_x.npz"]


def test_the_scene_cache_holds_only_scene_entries(tmp_path):
    _tree(tmp_path, ["scene_a-1f2e.npz", "scene_b-1f2e.skip.json", ".scene_c-1f2e.npz.tmp-123"])
    assert foreign_entries(tmp_path, SCENE_CACHE) == []
    _tree(tmp_path, ["data.csv"])
    assert foreign_entries(tmp_path, SCENE_CACHE) == ["data.csv"]


def test_a_lance_table_is_replaceable_and_a_user_folder_named_like_one_is_not(tmp_path):
    from pokeworld.swm.env import LANCE_TABLE

    table = tmp_path / "pokeworld.lance"
    _tree(table, ["data/0a1b.lance", "_versions/1.manifest", "_transactions/0-abc.txn"])
    assert foreign_entries(table, LANCE_TABLE) == []
    _tree(table, ["my_results.csv"])
    with pytest.raises(ConfigError, match="did not write"):
        check_owned_dir(table, LANCE_TABLE)


def test_a_failed_folder_write_removes_its_temporary_but_never_a_links_target(tmp_path):
    """atomic_path's temporary folder is removed entry by entry on failure: a link planted inside it is unlinked and
    the file it points at (outside, the user's) survives."""
    from pokeworld.io import atomic_path

    user = tmp_path / "user.txt"
    user.write_text("keep me")
    final = tmp_path / "out" / "store"
    with pytest.raises(RuntimeError):
        with atomic_path(final) as tmp:
            (tmp / "sub").mkdir(parents=True)
            (tmp / "sub" / "part.bin").write_bytes(b"x")
            (tmp / "link").symlink_to(user)
            (tmp / "dirlink").symlink_to(tmp_path, target_is_directory=True)
            raise RuntimeError("crash mid-write")
    assert user.read_text() == "keep me"
    assert not final.exists() and not list((tmp_path / "out").iterdir())


def test_stale_temporaries_are_the_only_files_removed(tmp_path):
    from pokeworld.io import remove_stale_temporaries

    (tmp_path / ".results.json.tmp-123").write_text("half")
    for name in ("results.json", "notes.tmp", ".hidden.tmp-x"):
        (tmp_path / name).write_text("keep")
    target = tmp_path / "target.txt"
    target.write_text("keep")
    os.symlink(target, tmp_path / ".link.tmp-7")  # a link under a temporary name: neither it nor its target goes
    assert remove_stale_temporaries(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [".hidden.tmp-x", ".link.tmp-7", "notes.tmp",
                                                          "results.json", "target.txt"]
    assert target.read_text() == "keep"


def test_the_writability_check_leaves_the_folder_as_it_was(tmp_path):
    from pokeworld.io import check_writable_dir

    (tmp_path / "mine.txt").write_text("keep")
    check_writable_dir(tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


def test_a_users_folder_named_like_a_temporary_is_left(tmp_path):
    """Only a private (0700) folder of this user, as temporary_folder makes, is removed under a temporary name."""
    import warnings

    from pokeworld.io import remove_stale_temporaries, temporary_folder

    user = tmp_path / ".notes.tmp-abcd1234"
    user.mkdir(mode=0o755)
    os.chmod(user, 0o755)
    (user / "draft.txt").write_text("mine")
    ours = temporary_folder(tmp_path / "results.json")
    (ours / "results.json").write_text("half")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert remove_stale_temporaries(tmp_path) == 1
    assert (user / "draft.txt").read_text() == "mine" and not ours.exists()
    assert any("not a private (0700) folder" in str(w.message) for w in caught)


def test_create_new_refuses_an_existing_name_and_a_link(tmp_path):
    from pokeworld.io import create_new

    create_new(tmp_path / "a.npy", b"abc")
    assert (tmp_path / "a.npy").read_bytes() == b"abc" and (tmp_path / "a.npy").stat().st_mode & 0o777 == 0o600
    with pytest.raises(FileExistsError):
        create_new(tmp_path / "a.npy", b"planted over")
    target = tmp_path / "user.txt"
    target.write_text("the user's")
    (tmp_path / "link.npy").symlink_to(target)
    with pytest.raises(OSError):
        create_new(tmp_path / "link.npy", b"through the link")
    assert target.read_text() == "the user's"


@pytest.mark.skipif(os.getuid() != 0, reason="giving a file to another user needs root")
def test_another_users_file_is_never_deleted(tmp_path):
    from pokeworld.io import remove_temporary

    theirs = tmp_path / "listed.json"
    theirs.write_text("{}")
    record_owned(theirs)  # even listed as ours, a file of another user was not written by this user's pokeworld
    os.chown(theirs, 12345, 12345)
    with pytest.raises(ConfigError, match="another user"):
        remove_own_file(theirs)
    assert theirs.exists()
    tmp = tmp_path / ".out.json.tmp-12345"  # an older temporary file's name
    tmp.write_text("half")
    os.chown(tmp, 12345, 12345)
    with pytest.warns(UserWarning, match="another user"):
        assert not remove_temporary(tmp)
    assert tmp.exists()
