"""A sqlite3 directory bag opened for bulk reading without rosbags' per-topic message counts.

rosbags' ``Sqlite3Reader`` counts the messages of every topic when it opens a file (a join over
the whole messages table, ~0.1 s for a 3-h bag), which a bulk read that scans the table anyway
does not need. :func:`open_sqlite3_bag` opens a plain sqlite3 directory bag from its
``metadata.yaml`` (rosbag2 versions 1-9) and each file's ``topics`` and ``message_definitions``
tables (the rosbag2 sqlite3 schema), applying rosbags' own checks: version <= 9, files present,
CDR serialisation. A bag it does not take (no metadata, MCAP, compressed files, an unexpected
schema, anything unreadable) gives None, and the caller opens it with rosbags' ``Reader``, which
also words the error of a broken bag.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

import apsw
import yaml
from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinition, MessageDefinitionFormat

_DEFINITION_FORMATS = {"ros2msg": MessageDefinitionFormat.MSG, "ros2idl": MessageDefinitionFormat.IDL}
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@dataclass(frozen=True)
class Sqlite3Bag:
    """An uncompressed sqlite3 directory bag, as :func:`open_sqlite3_bag` found it.

    Attributes
    ----------
    path : pathlib.Path
        The bag directory.
    files : list of pathlib.Path
        Its storage files, in the order of ``relative_file_paths``.
    connections : list of rosbags.interfaces.Connection
        One per topic of ``topics_with_message_count`` (as rosbags lists them), with the message
        definition a file embeds for its type, if any (QoS profiles are not parsed).
    custom_data : dict
        ``custom_data`` of the metadata (empty when absent).
    """

    path: Path
    files: list[Path]
    connections: list[Connection]
    custom_data: dict[str, str]


def connect(path: Path) -> apsw.Connection:
    """A read-only connection to one storage file (``immutable``, as rosbags opens it)."""
    return apsw.Connection(f"file:{path}?immutable=1", flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI)


def _definitions(path: Path) -> dict[str, MessageDefinition]:
    """``{type: definition}`` embedded in one file (schema >= 4); raises if it is not a rosbag2 file."""
    db = connect(path)
    try:
        tables = {name for (name,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if not {"messages", "topics"} <= tables:
            raise ValueError("not a rosbag2 sqlite3 file")
        schema = db.execute("SELECT schema_version FROM schema").fetchone()[0] if "schema" in tables else 0
        if schema < 4:
            return {}
        found: dict[str, MessageDefinition] = {}
        for name, encoding, text in db.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions ORDER BY id"):
            if name not in found and encoding in _DEFINITION_FORMATS:
                found[name] = MessageDefinition(_DEFINITION_FORMATS[encoding], text)
        return found
    finally:
        db.close()


def open_sqlite3_bag(bag: Path) -> Sqlite3Bag | None:
    """The sqlite3 directory bag at ``bag``, or None when rosbags' ``Reader`` must open it."""
    try:
        info: dict[str, Any] = yaml.load((bag / "metadata.yaml").read_text(encoding="utf-8"),
                                         Loader=_SAFE_LOADER)["rosbag2_bagfile_information"]
        if info["storage_identifier"] != "sqlite3" or int(info["version"]) > 9:
            return None
        if (info.get("compression_mode") or "none").lower() != "none":
            return None
        files = [bag / PurePath(str(name)).name for name in info["relative_file_paths"]]
        if not files or not all(f.is_file() for f in files):
            return None
        definitions: dict[str, MessageDefinition] = {}
        for path in files:
            for name, definition in _definitions(path).items():
                definitions.setdefault(name, definition)
        connections = []
        for index, entry in enumerate(info["topics_with_message_count"]):
            meta = entry["topic_metadata"]
            if meta["serialization_format"] != "cdr":
                return None
            connections.append(Connection(
                id=index + 1, topic=meta["name"], msgtype=meta["type"],
                msgdef=definitions.get(meta["type"], MessageDefinition(MessageDefinitionFormat.NONE, "")),
                digest=meta.get("type_description_hash", "") or "", msgcount=int(entry["message_count"]),
                ext=ConnectionExtRosbag2(serialization_format="cdr", offered_qos_profiles=[]), owner=None))
        custom = info.get("custom_data") or {}
        return Sqlite3Bag(bag, files, connections, {str(k): str(v) for k, v in custom.items()})
    except Exception:  # any surprise: rosbags opens it (and names the problem if it is broken)
        return None
