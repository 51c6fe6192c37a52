"""A ROS bag's files, checked before rosbags opens any: regular files, and a ROS 2 ``metadata.yaml`` read safely.

Opening a FIFO blocks (sqlite opens a ``.db3`` that is one and never returns, even on SIGTERM), so every file
of a bag is checked with :func:`ineid._inputs.regular_file` first: a ROS 1 ``.bag`` or a bare ``.mcap``, or a
ROS 2 bag folder's ``metadata.yaml`` and the storage files it lists. The metadata is read here with the safe
YAML loader (a Python tag such as ``!!python/object/apply`` is refused, never run), within
:data:`METADATA_BYTES`, and each fault of it is one line naming the file and the line: the YAML error, the
QoS profiles rosbag2 before version 9 wrote as YAML text inside it, text that is not UTF-8, a document
that is no bag's metadata.
"""

from __future__ import annotations

from pathlib import Path, PurePath

from ineid._inputs import regular_file
from ineid.errors import DatasetError

METADATA_BYTES = 16 * 2**20
"""The largest ROS 2 ``metadata.yaml`` ineid reads (16 MiB): rosbag2 writes a few kB, under 1 MB for a bag of
a thousand files and topics."""


def check_bag_files(path: Path, kind: str) -> None:
    """Every file of the bag is a regular file, checked before anything is opened; a ROS 2 bag's
    ``metadata.yaml`` is at most :data:`METADATA_BYTES` of YAML that the safe loader reads.

    Raises:
        InputFileError: a file of the bag is missing, a FIFO, a device or a folder (or the metadata too large).
        DatasetError: the metadata is not YAML, not a bag's, or holds a tag the safe loader refuses (Python
            objects): one line naming the file and the line.
    """
    if kind != "ros2":
        regular_file(path, "the ROS bag")
        return
    folder = path if path.is_dir() else path.parent
    meta = regular_file(
        folder / "metadata.yaml",
        "the ROS 2 bag's metadata",
        max_bytes=METADATA_BYTES,
        limit_name="ineid.data.recordings.bag_metadata.METADATA_BYTES",
    )
    info = _bag_metadata(meta)
    files = info.get("relative_file_paths")
    for name in files if isinstance(files, list) else []:
        regular_file(folder / PurePath(str(name)).name, "a file of the ROS 2 bag")


def _bag_metadata(meta: Path) -> dict:
    """The ``rosbag2_bagfile_information`` of a ``metadata.yaml``, read by the safe loader (no Python tags)."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    fix = "a ROS 2 bag's metadata.yaml is the YAML text rosbag2 writes: restore it"
    raw = meta.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise DatasetError(f"{meta}, line {line}: not UTF-8 text; {fix}") from None
    try:
        data = YAML(typ="safe").load(text)
    except YAMLError as e:
        raise DatasetError(f"{meta}, line {_yaml_line(e, text)}: {_yaml_problem(e)}; {fix}") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise DatasetError(f"{meta}, line 1: no rosbag2_bagfile_information mapping, so not a bag's metadata; {fix}")
    topics = info.get("topics_with_message_count")
    for k, topic in enumerate(topics if isinstance(topics, list) else []):
        about = topic.get("topic_metadata") if isinstance(topic, dict) else None
        qos = about.get("offered_qos_profiles") if isinstance(about, dict) else None
        if not isinstance(qos, str):
            continue
        try:  # rosbag2 before version 9 wrote the QoS profiles as YAML text inside the YAML
            YAML(typ="safe").load(qos)
        except YAMLError as e:
            line = _node_line(
                YAML(typ="safe").compose(text),
                (
                    "rosbag2_bagfile_information",
                    "topics_with_message_count",
                    k,
                    "topic_metadata",
                    "offered_qos_profiles",
                ),
            )
            raise DatasetError(
                f"{meta}, line {line}: the offered_qos_profiles of topic {k} are not YAML (their line "
                f"{_yaml_line(e, qos)}: {_yaml_problem(e)}); {fix}"
            ) from None
    return info


def _yaml_line(e: Exception, text: str) -> int:
    """The line (from 1) a YAML error names."""
    mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
    if mark is not None:
        return int(mark.line) + 1
    position = getattr(e, "position", None)  # the reader's errors (a control character) give a position
    return text.count("\n", 0, position) + 1 if isinstance(position, int) else 1


def _yaml_problem(e: Exception) -> str:
    """A YAML error's problem, on one line, without the quote of the file (the line is said apart)."""
    problem = getattr(e, "problem", None) or str(e).split("\n")[0]
    return " ".join(str(problem).split())[:200]


def _node_line(node, keys: tuple) -> int:
    """The line (from 1) of the YAML node at ``keys`` (mapping keys and sequence indices) below ``node``."""
    for key in keys:
        if isinstance(node.value, list) and isinstance(key, int):
            node = node.value[key]
        else:
            node = next(v for k, v in node.value if k.value == key)
    return int(node.start_mark.line) + 1
