"""Open ROS 2 bags with rosbags, turning every failure into a one-line :class:`BagError`.

A bag is a directory with ``metadata.yaml`` (any rosbag2 version rosbags reads, MCAP or sqlite3
storage, one or more files) or a single ``.mcap`` / ``.db3`` storage file. Message definitions
embedded in a bag are checked against the installed ones and, for types this workspace does not
know, registered in the shared type store so the bag can be decoded and played.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.typesys import get_types_from_idl, get_types_from_msg
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore

from taiji2_runtime.bag.errors import BagError

if TYPE_CHECKING:
    from rosbags.rosbag2 import Reader

# rosbags.rosbag2 (its readers and writer, ~0.04 s to import) is imported where a bag is opened
# with it: reading a sqlite3 bag directly (sqlite3_direct) or only checking types does not need it

_STORAGE_SUFFIXES = (".mcap", ".db3")


def check_bag_path(path: str | Path) -> Path:
    """The bag path, checked to be a rosbag2 directory or a storage file.

    Raises
    ------
    BagError
        If the path does not exist, is an empty directory, or a directory without ``metadata.yaml``.
    """
    bag = Path(path)
    if not bag.exists():
        raise BagError(bag, "no such bag (the path does not exist)")
    if bag.is_dir():
        if (bag / "metadata.yaml").is_file():
            return bag
        files = sorted(p.name for p in bag.iterdir())
        if not files:
            raise BagError(bag, "not a ROS 2 bag: the directory is empty")
        storage = [f for f in files if f.endswith(_STORAGE_SUFFIXES)]
        hint = f" (it holds {storage[0]}: pass that file to read it without metadata)" if storage else ""
        raise BagError(bag, f"not a ROS 2 bag: no metadata.yaml{hint}")
    if bag.suffix not in _STORAGE_SUFFIXES:
        raise BagError(bag, "not a ROS 2 bag: expected a bag directory, a .mcap or a .db3 file")
    if bag.stat().st_size == 0:
        raise BagError(bag, "the storage file is empty")
    return bag


def describe_error(exc: BaseException) -> str:
    """One-line text of a rosbags / sqlite / OS error met while reading a bag."""
    text = " ".join(str(exc).split()).rstrip(".")
    if len(text) > 120:
        text = text[:117] + "..."
    from rosbags.rosbag2.errors import ReaderError

    kind = type(exc).__name__
    if isinstance(exc, ReaderError):
        return f"corrupt or truncated bag ({text})"
    if kind in ("SQLError", "CorruptError", "NotADBError", "DatabaseError", "IOError") or "apsw" in type(
            exc).__module__:
        return f"corrupt sqlite3 storage ({kind}: {text})" if text else f"corrupt sqlite3 storage ({kind})"
    if isinstance(exc, UnicodeDecodeError):
        return "corrupt bag (undecodable text in the metadata or definitions)"
    if isinstance(exc, OSError):
        return f"cannot read the bag ({text or kind})"
    return f"corrupt bag ({kind}: {text})" if text else f"corrupt bag ({kind})"


def _culprit(bag: Path) -> Path | None:
    """The first storage file of a directory bag that does not open on its own (to name it)."""
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    if not bag.is_dir():
        return None
    try:
        with (bag / "metadata.yaml").open(encoding="utf-8") as stream:
            info = yaml.safe_load(stream)["rosbag2_bagfile_information"]
        names = [Path(str(name)).name for name in info["relative_file_paths"]]
        plugin = Sqlite3Reader if info.get("storage_identifier") == "sqlite3" else McapReader
    except Exception:  # the metadata itself is the problem
        return bag / "metadata.yaml"
    for name in names:
        storage = plugin(bag / name)
        try:
            storage.open()
        except Exception:  # this file is the broken one
            return bag / name
        storage.close()
    return None


@contextmanager
def open_reader(path: str | Path) -> Iterator[Reader]:
    """An open rosbags :class:`~rosbags.rosbag2.Reader` of ``path``; errors become :class:`BagError`.

    Errors raised while the caller iterates messages inside the ``with`` block are converted too.
    """
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.errors import ReaderError

    bag = check_bag_path(path)
    repair_dir = None
    try:
        reader = Reader(bag)
        reader.open()
    except BagError:
        raise
    except Exception as exc:  # rosbags, apsw, yaml, struct, OS errors: all mean "cannot read"
        truncated = _truncated_mcap(bag, exc)
        if truncated is None:
            raise BagError(_culprit(bag) or bag, describe_error(exc)) from exc
        reader, repair_dir = _open_repaired(truncated, exc)
    try:
        yield reader
    except (ReaderError, OSError, EOFError, struct.error) as exc:
        raise BagError(bag, describe_error(exc)) from exc
    except Exception as exc:
        if type(exc).__module__.split(".")[0] in ("apsw", "rosbags", "zstd", "lz4", "backports", "compression"):
            raise BagError(bag, describe_error(exc)) from exc
        raise
    finally:
        try:
            reader.close()
        except Exception:  # closing a broken reader must not hide the first error
            pass
        if repair_dir is not None:
            repair_dir.cleanup()


#: rosbags' words for an MCAP file whose end (footer, summary) is missing or damaged
_MCAP_END_ERRORS = ("File end magic is invalid", "Invalid MCAP footer", "Invalid MCAP summary offset")


def _truncated_mcap(bag: Path, exc: BaseException) -> Path | None:
    """The one MCAP file of ``bag`` when opening it failed at its end (a cut recording), else None."""
    if not any(words in str(exc) for words in _MCAP_END_ERRORS):
        return None
    files = [bag] if bag.is_file() else sorted(bag.glob("*.mcap"))
    return files[0] if len(files) == 1 and files[0].suffix == ".mcap" else None


def _open_repaired(mcap: Path, exc: BaseException) -> tuple[Reader, Any]:
    """A reader of the complete records of a truncated MCAP file (:mod:`.mcap_repair`), with a warning that
    says how much was recovered, and the temporary directory that holds the repaired copy."""
    import logging
    import tempfile

    from rosbags.rosbag2 import Reader

    from taiji2_runtime.bag.mcap_repair import repaired_copy

    directory = tempfile.TemporaryDirectory(prefix="taiji2-mcap-repair-")
    try:
        repair = repaired_copy(mcap, Path(directory.name))
        reader = Reader(repair.path)
        reader.open()
        if reader.message_count == 0:  # cut inside its first chunk: nothing to recover, the original error stands
            reader.close()
            raise ValueError("no complete message")
    except Exception:
        directory.cleanup()
        raise BagError(mcap, describe_error(exc)) from exc
    logging.getLogger("taiji2.bag").warning("warning: %s; %d messages recovered", repair.note(mcap),
                                            reader.message_count)
    return reader, directory


def storage_identifier(reader: Reader) -> str:
    """``"mcap"`` or ``"sqlite3"``: the storage of an open reader."""
    from rosbags.rosbag2.storage_sqlite3 import Sqlite3Reader

    storages = storages_of(reader)
    if storages:
        return "sqlite3" if isinstance(storages[0], Sqlite3Reader) else "mcap"
    return "sqlite3" if Path(str(reader.path)).suffix == ".db3" else "mcap"


def storages_of(reader: Reader) -> list[Any]:
    """The per-file storage readers (rosbags ``McapReader`` / ``Sqlite3Reader``) of an open reader."""
    storages = getattr(reader.storage, "storages", None)
    return list(storages) if storages is not None else [reader.storage]


def bag_files(path: str | Path) -> list[Path]:
    """The storage files of a bag, in the order its metadata lists them."""
    bag = check_bag_path(path)
    if bag.is_file():
        return [bag]
    with open_reader(bag) as reader:
        return [Path(str(s.path)) for s in storages_of(reader)]


def custom_data(reader: Reader) -> dict[str, str]:
    """The ``custom_data`` of a bag's metadata (empty when absent)."""
    metadata = getattr(reader.storage, "metadata", None)
    custom = getattr(metadata, "custom", None)
    return {str(k): str(v) for k, v in (custom or {}).items()}


@dataclass(frozen=True)
class TypeCheck:
    """Outcome of checking one message type of a bag against the installed definitions.

    Attributes
    ----------
    msgtype : str
        ``pkg/msg/Name``.
    usable : bool
        True when messages of this type can be decoded (known type with the same definition, or a
        type registered from the bag's embedded definition).
    note : str
        Empty, ``"registered from the bag's definition"``, or why the type is unusable.
    """

    msgtype: str
    usable: bool
    note: str = ""


def _parse_definition(connection: Connection) -> dict[str, Any] | None:
    msgdef = connection.msgdef
    if msgdef.format == MessageDefinitionFormat.NONE or not msgdef.data.strip():
        return None
    if msgdef.format == MessageDefinitionFormat.IDL:
        return dict(get_types_from_idl(msgdef.data))
    return dict(get_types_from_msg(msgdef.data, connection.msgtype))


def check_types(connections: list[Connection], store: Typestore) -> dict[str, TypeCheck]:
    """Check every message type of ``connections`` against ``store``; register unknown ones.

    A type whose embedded definition differs from the installed one is unusable (decoding it with
    the installed layout would give wrong values). A type unknown to ``store`` is registered from
    the bag's embedded definition when there is one.
    """
    result: dict[str, TypeCheck] = {}
    for connection in connections:
        msgtype = connection.msgtype
        if msgtype in result:
            continue
        known = msgtype in store.fielddefs
        try:
            parsed = _parse_definition(connection)
        except Exception as exc:  # any parser failure: the definition text is unusable
            parsed = None
            if not known:
                result[msgtype] = TypeCheck(msgtype, False, f"unknown type; its embedded definition does not "
                                                           f"parse ({type(exc).__name__})")
                continue
        if parsed is None:
            result[msgtype] = (TypeCheck(msgtype, True) if known else
                               TypeCheck(msgtype, False, "unknown type and no definition in the bag"))
            continue
        if msgtype not in parsed:
            result[msgtype] = TypeCheck(msgtype, known, "" if known else "embedded definition does not define it")
            continue
        try:
            store.register(parsed)
        except TypesysError as exc:
            found = re.search(r"Type '([^']+)'", str(exc))
            culprit = found.group(1) if found else msgtype
            detail = "" if culprit == msgtype else f" (in its part {culprit})"
            result[msgtype] = TypeCheck(msgtype, False, f"the bag's definition differs from the installed one{detail}")
            continue
        except Exception as exc:
            result[msgtype] = TypeCheck(msgtype, known, "" if known else f"cannot register its definition "
                                                                        f"({type(exc).__name__})")
            continue
        result[msgtype] = TypeCheck(msgtype, True, "" if known else "registered from the bag's definition")
    return result
