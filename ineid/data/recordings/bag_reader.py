"""Opening a ROS bag with ``rosbags``: its kind (ROS 1, ROS 2 folder, bare MCAP), its readers, one error line.

:func:`open_bag` gives the bag's connections, its messages and their deserializer alike for the three kinds
(a private class reads a bare ``.mcap`` file, which rosbags' ``AnyReader`` does not); what is read from the
messages is :mod:`ineid.data.recordings.bags`'.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ineid.data.recordings.bag_metadata import check_bag_files
from ineid.errors import DatasetError


def bag_kind(path: Path) -> str:
    """``"ros1"``, ``"ros2"`` (a folder with ``metadata.yaml``) or ``"mcap"`` (a bare MCAP file)."""
    if path.is_dir():
        if not (path / "metadata.yaml").exists():
            raise DatasetError(
                f"{path} is a folder without metadata.yaml, not a ROS 2 bag; give the bag folder, "
                "a ROS 1 .bag file, a .mcap file or a CSV file"
            )
        return "ros2"
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return "ros1"
    if suffix in (".mcap", ".db3"):
        if (path.parent / "metadata.yaml").exists():
            return "ros2"
        if suffix == ".mcap":
            return "mcap"
        raise DatasetError(f"{path}: a .db3 file needs its bag folder (with metadata.yaml); give the folder")
    raise DatasetError(f"{path}: not a ROS bag (.bag, .mcap, or a ROS 2 bag folder)")


@contextmanager
def open_bag(path: Path):
    """Open the bag at ``path`` (its files checked first: :func:`ineid.data.recordings.bag_metadata.check_bag_files`).

    Yields:
        ``(connections, messages(conns) -> iterator of (conn, log_ns, raw), deserialize(raw, type))``; the bag
        is closed after.

    Raises:
        DatasetError: the bag cannot be read (also while its messages are read within the ``with``), in one line.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    errors = (AnyReaderError, Reader1Error, Reader2Error, SerdeError, TypesysError, OSError, KeyError, ValueError)
    kind = bag_kind(path)
    check_bag_files(path, kind)
    try:
        if kind == "mcap":
            reader = _McapFile(path)
            reader.open()
            try:
                yield reader.connections, reader.messages, reader.deserialize
            finally:
                reader.close()
            return
        target = path.parent if kind == "ros2" and not path.is_dir() else path
        with AnyReader([target]) as reader:
            yield reader.connections, lambda conns: reader.messages(connections=conns), reader.deserialize
    except DatasetError:
        raise
    except errors as e:
        text = " ".join(str(e).split())  # one line: a reader's message may quote the file over several
        raise DatasetError(
            f"{path}: cannot be read as a ROS bag ({type(e).__name__}: "
            f"{text if len(text) <= 300 else text[:297] + '...'})"
        ) from None


class _McapFile:
    """A bare ROS 2 ``.mcap`` file (no ``metadata.yaml``), through rosbags' MCAP storage reader."""

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag2.storage_mcap import McapReader

        self._reader = McapReader(path)
        self.connections: list = []
        self._typestore = None

    def open(self) -> None:
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

        self._reader.open()
        self.connections = list(self._reader.connections)
        types: dict = {}
        sep = "=" * 80 + "\n"
        for conn in self.connections:
            fmt, text = conn.msgdef.format, conn.msgdef.data
            if fmt == MessageDefinitionFormat.MSG:
                types.update(get_types_from_msg(text, conn.msgtype))
            elif fmt == MessageDefinitionFormat.IDL:
                parts = text.split(sep)[1:] if text.startswith(f"{sep}IDL: ") else [text]
                for part in parts:
                    types.update(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        self._typestore = store

    def messages(self, conns) -> Iterator:
        return self._reader.messages(conns)

    def deserialize(self, raw: bytes, msgtype: str):
        return self._typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        self._reader.close()
