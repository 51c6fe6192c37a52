"""The names ineid makes up beside an output (:mod:`ineid._atomic`, :mod:`ineid._temporary`): temporaries
are new files of unpredictable names, never links; lock files are never written through; the stale
cleanup removes only what ineid made; any legal output name fits; a folder swap is never cut by a signal."""

from __future__ import annotations

import errno
import os
import signal
import stat

import pytest

from ineid import _temporary
from ineid._atomic import atomic_write, lock_path, output_lock, replace_folder, staging_folder
from ineid._faults import describe_fault
from ineid._temporary import (
    NAME_MAX,
    create_temporary,
    remove_stale_temporaries,
    target_name,
    temporary_path,
)
from ineid.errors import StorageError


def dead_pid() -> int:
    """A process id no process has now."""
    for pid in range(999999, 900000, -1):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except PermissionError:
            continue
    raise AssertionError("no free pid")


def as_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture
def victim(tmp_path):
    """A file of the user's outside the output's folder, which a planted link points at."""
    path = tmp_path / "elsewhere" / "victim.txt"
    path.parent.mkdir()
    path.write_bytes(b"the user's data")
    return path


# -- temporaries -------------------------------------------------------------------------------------


def test_a_temporary_is_a_new_file_never_a_link(tmp_path, victim, monkeypatch):
    out = tmp_path / "o.h5"
    tokens = iter(["0123abcd", "4567cdef"])
    monkeypatch.setattr(_temporary.secrets, "token_hex", lambda n: next(tokens))
    planted = tmp_path / f".o.h5.ineid-{os.getpid()}-0123abcd.tmp.h5"
    planted.symlink_to(victim)  # someone guessed the first name: it is skipped, not opened
    tmp = create_temporary(out, ".h5")
    assert tmp.name == f".o.h5.ineid-{os.getpid()}-4567cdef.tmp.h5"
    st = tmp.lstat()
    assert stat.S_ISREG(st.st_mode) and st.st_size == 0
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(st.st_mode) == 0o666 & ~umask  # the output's mode, as any writer's new file
    assert target_name(tmp.name) == "o.h5" and target_name(planted.name) == "o.h5"
    assert target_name(".o.h5.4000000.tmp") is None and target_name("o.h5") is None
    assert victim.read_bytes() == b"the user's data" and planted.is_symlink()


def test_a_staging_folder_and_the_folder_set_aside_are_new_folders(tmp_path, victim, monkeypatch):
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.msgpack").write_bytes(b"old")
    tokens = iter(["00000000", "11111111", "00000000", "22222222"])
    monkeypatch.setattr(_temporary.secrets, "token_hex", lambda n: next(tokens))
    (tmp_path / f".run.ineid-{os.getpid()}-00000000.tmp").symlink_to(victim.parent)
    (tmp_path / f".run.ineid-{os.getpid()}-00000000.old").symlink_to(victim.parent)
    new = staging_folder(run)
    assert new.name == f".run.ineid-{os.getpid()}-11111111.tmp" and not new.is_symlink()
    (new / "model.msgpack").write_bytes(b"new")
    replace_folder(new, run)
    assert (run / "model.msgpack").read_bytes() == b"new"
    assert sorted(p.name for p in victim.parent.iterdir()) == ["victim.txt"]
    assert sorted(p.name for p in tmp_path.iterdir() if not p.is_symlink()) == ["elsewhere", "run"]


def test_a_signal_during_a_folder_swap_waits_until_the_new_folder_is_in_place(tmp_path, monkeypatch):
    class Stop(Exception):
        pass

    def stop(signum, frame):
        raise Stop

    run = tmp_path / "run"
    run.mkdir()
    (run / "model.msgpack").write_bytes(b"old")
    new = staging_folder(run)
    (new / "model.msgpack").write_bytes(b"new")
    rename = os.rename

    def signalled(a, b):  # SIGTERM arrives between the two renames
        os.kill(os.getpid(), signal.SIGTERM)
        rename(a, b)

    old = signal.signal(signal.SIGTERM, stop)
    try:
        monkeypatch.setattr(os, "rename", signalled)
        with pytest.raises(Stop):
            replace_folder(new, run)
    finally:
        monkeypatch.undo()
        signal.signal(signal.SIGTERM, old)
    assert (run / "model.msgpack").read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


# -- any legal name --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["d" * 250 + ".h5", "\u00e9" * 126 + ".h5"], ids=["253 characters", "255 bytes"])
def test_the_longest_legal_names_can_be_written(tmp_path, name):
    out = tmp_path / name
    tmp = temporary_path(out, out.suffix)
    assert len(os.fsencode(tmp.name)) <= NAME_MAX and len(os.fsencode(lock_path(out).name)) <= NAME_MAX
    assert target_name(tmp.name) == name  # a fault names the output, not its temporary
    assert describe_fault(OSError(errno.ENOSPC, "No space left on device", str(tmp))) == (
        f"no space left on device writing {str(out)[:60]}...{str(out)[-40:]}; free some space or choose another --out"
    )
    with output_lock(out):
        atomic_write(out, "data")
    assert out.read_text() == "data" and [p.name for p in tmp_path.iterdir()] == [name]


# -- lock files ---------------------------------------------------------------------------------------------


def refused(out, what):
    with pytest.raises(StorageError) as e, output_lock(out):
        pass
    assert str(e.value) == f"{lock_path(out)} {what}, not a lock file of ineid; remove it, or choose another --out"


def test_a_lock_name_taken_by_something_else_is_refused_never_written(tmp_path, victim):
    out = tmp_path / "o.h5"
    lock = lock_path(out)
    lock.symlink_to(victim)
    refused(out, "is a symbolic link")
    lock.unlink()
    os.link(victim, lock)  # a hard link: the same file under the lock's name
    refused(out, "has other names (hard links)")
    lock.unlink()
    os.mkfifo(lock)  # never opened: a FIFO would block, a device could act
    refused(out, "is not a regular file")
    lock.unlink()
    lock.write_text("notes of the user\n")
    refused(out, "holds other data")
    assert victim.read_bytes() == b"the user's data" and lock.read_text() == "notes of the user\n"
    lock.write_text("4000000\n")  # a lock file a killed run left: reused, then removed
    with output_lock(out):
        assert lock.read_text() == f"{os.getpid()}\n"
    assert not lock.exists()


@pytest.mark.skipif(not as_root(), reason="needs root to give a file to another user")
def test_another_users_lock_file_is_locked_not_written(tmp_path):
    tmp_path.chmod(0o1777)  # a shared folder, as /tmp
    out = tmp_path / "o.h5"
    lock = lock_path(out)
    lock.write_text("")
    os.chown(lock, 65534, 65534)
    with output_lock(out):
        assert lock.read_text() == ""


# -- stale temporaries ----------------------------------------------------------------------------------


def test_the_stale_cleanup_removes_only_what_ineid_made(tmp_path, victim):
    pid = dead_pid()
    out = tmp_path / "o.h5"
    stale = tmp_path / f".o.h5.ineid-{pid}-0123abcd.tmp"
    stale.write_bytes(b"half a dataset")
    folder = tmp_path / f".o.h5.ineid-{pid}-89abcdef.tmp"
    folder.mkdir()
    (folder / "x").write_bytes(b"half a run")
    link = tmp_path / f".o.h5.ineid-{pid}-4567cdef.tmp"  # a link at an exact name: neither followed nor removed
    link.symlink_to(victim)
    kept = [
        ".o.h5.4000000.tmp.notes",  # the user's, named like a temporary of another scheme
        f".o.h5.{pid}.tmp",
        f".o.h5.ineid-{pid}-0123abcd.tmp.notes",  # a suffix ineid never gives this output's temporaries
        f".o.h5.ineid-{pid}-0123abcd.old.h5",
        f".o.h5.ineid-{pid}-0123.tmp",
    ]
    for name in kept:
        (tmp_path / name).write_bytes(b"mine")
    assert sorted(remove_stale_temporaries(out)) == sorted([stale, folder])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["elsewhere", link.name, *kept])
    assert victim.read_bytes() == b"the user's data"
    if as_root():  # another user's file at an exact name of a dead pid: not ours to remove
        stale.write_bytes(b"theirs")
        os.chown(stale, 65534, 65534)
        assert remove_stale_temporaries(out) == [] and stale.read_bytes() == b"theirs"
