"""The HDF5 files ineid reads hold their data inside themselves: links and storage that reach out are refused.

HDF5 lets a file point elsewhere: an external link (``h5py.ExternalLink``) names an object of
another file, a soft link names a path that may not exist or may loop back on itself, a virtual
dataset maps other files' datasets, and external raw storage (``external=[(file, offset, size)]``)
makes any file's bytes (``/etc/passwd``) read as a dataset's numbers. ineid writes none of these (its
datasets and results files hold groups, datasets and hard links only), so a file that has one was
not written by ineid, or was edited. :func:`audit_hdf5` walks every link of an open file without
following any link that is not a hard link, and refuses such a file in one
:class:`~ineid.errors.InputFileError` line naming the object, before anything is read from it.
"""

from __future__ import annotations

from pathlib import Path

from ineid.errors import InputFileError

MAX_HDF5_LINKS = 100_000
"""The most links :func:`audit_hdf5` walks in one file: ineid's datasets and results files hold a few
dozen (a results file with payloads a few hundred); a file with more was not written by ineid."""

_NOT_INEIDS = "ineid reads only data stored inside the file (this file was not written by ineid, or was edited)"


def _refuse(path: Path, what: str) -> InputFileError:
    return InputFileError(f"{path}: {what}; {_NOT_INEIDS}; regenerate it with ineid")


def _check_dataset(path: Path, name: str, dset) -> None:
    """Refuse a virtual dataset or one whose bytes are stored in other files."""
    if dset.is_virtual:
        sources = sorted({s.file_name for s in dset.virtual_sources()})
        shown = ", ".join(repr(s) for s in sources[:3]) + (", ..." if len(sources) > 3 else "")
        raise _refuse(path, f"dataset {name!r} is a virtual dataset (its data lives in {shown})")
    external = dset.external
    if external:
        file = external[0][0]
        file = file.decode(errors="replace") if isinstance(file, bytes) else str(file)
        raise _refuse(path, f"dataset {name!r} keeps its data in the external file {file!r}")


def _walk(f, path: Path) -> None:
    import h5py

    seen = {hash(f.id)}
    groups = [("", f)]
    count = 0
    while groups:
        prefix, group = groups.pop()
        for key in group:
            name = f"{prefix}/{key}"
            count += 1
            if count > MAX_HDF5_LINKS:
                raise _refuse(path, f"it holds more than {MAX_HDF5_LINKS:,} links (MAX_HDF5_LINKS)")
            link = group.get(key, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                raise _refuse(path, f"{name!r} is an external link to {link.path!r} in the file {link.filename!r}")
            if isinstance(link, h5py.SoftLink):
                raise _refuse(path, f"{name!r} is a soft link (to {link.path!r})")
            if not isinstance(link, h5py.HardLink):
                raise _refuse(path, f"{name!r} is a link of a kind ineid does not follow ({type(link).__name__})")
            obj = group[key]
            if hash(obj.id) in seen:  # a second hard link to a group already walked (a loop, or a shared group)
                continue
            seen.add(hash(obj.id))
            if isinstance(obj, h5py.Dataset):
                _check_dataset(path, name, obj)
            elif isinstance(obj, h5py.Group):
                groups.append((name, obj))


def audit_hdf5(f, path: str | Path) -> None:
    """Check the open HDF5 file ``f`` holds nothing that reaches outside it; nothing is read from its datasets.

    Walks every link from the root: only hard links are followed (each group once), and each
    dataset's storage is checked.

    Raises:
        InputFileError: an external or soft link (a soft-link loop included), a link of a user-defined
            class, a virtual dataset, external raw storage, more than :data:`MAX_HDF5_LINKS` links, or
            links that cannot be read; the message names the object and says the file was not written
            by ineid.
    """
    path = Path(path)
    try:
        _walk(f, path)
    except InputFileError:
        raise
    except (KeyError, RuntimeError, OSError, ValueError, TypeError) as e:
        text = str(e).strip().splitlines()
        raise _refuse(path, f"its links cannot be read ({text[0] if text else type(e).__name__})") from None
