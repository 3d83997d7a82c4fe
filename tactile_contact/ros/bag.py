"""Record the pipeline's topics to rosbag2 files and replay them, with plain rclpy.

Reading (:func:`read_messages`) needs no ROS; recording and replaying take an rclpy node.

rosbag2 itself is not on PyPI, so bags are written and read with the ``rosbags`` library
(sqlite3 or MCAP storage, rosbag2 format version 8 or 9) and travel through rclpy as raw CDR:
recording subscribes with ``raw=True`` and stores the bytes as received; replaying publishes
the stored bytes unchanged. A bag written here plays in ``ros2 bag play`` and Foxglove, and a
bag recorded there replays here.
"""

from __future__ import annotations

import importlib
import sys
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import yaml
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

_PACKAGE = "tactile_contact"


def _qos(reliable: bool) -> Any:
    # A best-effort subscription matches reliable and best-effort publishers alike, and a
    # reliable publisher matches both kinds of subscription; the depth absorbs bursts. rclpy
    # is imported here, not at the top: reading a bag (read_messages) needs no ROS.
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    policy = ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(depth=200, reliability=policy)


class BagError(RuntimeError):
    """A bag cannot be written or read as asked (names the file and the reason)."""


def message_class(msgtype: str) -> type:
    """The rclpy message class for ``"pkg/msg/Name"`` (or ``"pkg/Name"``)."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3:
        raise BagError(f"not a ROS message type name: {msgtype!r}")
    module = importlib.import_module(f"{parts[0]}.{parts[1]}")
    try:
        return getattr(module, parts[2])
    except AttributeError:
        raise BagError(f"no message {parts[2]!r} in {parts[0]}.{parts[1]}") from None


def message_type_name(cls: type) -> str:
    """``"pkg/msg/Name"`` for an rclpy message class."""
    pkg, kind = cls.__module__.split(".")[:2]
    return f"{pkg}/{kind}/{cls.__name__}"


def _own_definitions() -> dict[str, str]:
    """Definitions of this package's messages (source tree or installed share directory)."""
    candidates = [
        Path(__file__).resolve().parents[2] / "msg",
        Path(sys.prefix) / "share" / _PACKAGE / "msg",
    ]
    for folder in candidates:
        files = sorted(folder.glob("*.msg"))
        if files:
            return {f"{_PACKAGE}/msg/{f.stem}": f.read_text() for f in files}
    raise BagError(f"cannot find the {_PACKAGE} message definitions (looked in {candidates})")


def typestore() -> Any:
    """A rosbags typestore of ROS 2 Kilted plus this package's messages."""
    store = get_typestore(Stores.ROS2_KILTED)
    types: dict[str, Any] = {}
    for name, text in _own_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


class BagRecorder:
    """Writes every message of the given topics, as raw CDR, into a new rosbag2 bag.

    Args:
        node: an rclpy node whose executor delivers the messages.
        path: bag directory to create; refused if it exists (a bag is never overwritten).
        topics: topic name → rclpy message class.
        storage: "mcap" or "sqlite3".
    """

    def __init__(
        self,
        node: Any,
        path: str | Path,
        topics: Mapping[str, type],
        storage: str = "mcap",
    ) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path}: exists; a bag is never overwritten")
        plugins = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise BagError(f"storage {storage!r}: expected one of {sorted(plugins)}")
        self._node = node
        self._lock = threading.Lock()
        self._store = typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=plugins[storage])
        self._writer.open()
        self.counts: dict[str, int] = {}
        self._subs = []
        for topic, cls in topics.items():
            conn = self._writer.add_connection(topic, message_type_name(cls), typestore=self._store)
            self.counts[topic] = 0
            self._subs.append(
                node.create_subscription(
                    cls, topic, self._make_callback(topic, conn), _qos(False), raw=True
                )
            )

    def _make_callback(self, topic: str, conn: Any) -> Any:
        def on_message(data: bytes) -> None:
            stamp = self._node.get_clock().now().nanoseconds
            with self._lock:
                if self._writer is None:
                    return
                self._writer.write(conn, stamp, data)
                self.counts[topic] += 1

        return on_message

    def close(self) -> None:
        """Stop recording and finish the bag (metadata written)."""
        for sub in self._subs:
            self._node.destroy_subscription(sub)
        self._subs = []
        with self._lock:
            if self._writer is not None:
                self._writer.close()
                self._writer = None

    def __enter__(self) -> BagRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_messages(
    path: str | Path, topics: Iterable[str] | None = None
) -> list[tuple[str, int, Any]]:
    """All messages of ``topics`` (all when None) as (topic, receive time [ns], message).

    Messages are deserialised with rosbags (not rclpy), which makes this a check independent
    of the publishing side. Raises :class:`BagError` like :func:`load_raw`.
    """
    store = typestore()
    out = []
    for topic, stamp, data, msgtype in load_raw(path, topics):
        try:
            out.append((topic, stamp, store.deserialize_cdr(data, msgtype)))
        except Exception as exc:
            raise BagError(f"{path}: a message of {topic} does not decode: {exc}") from None
    return out


def load_raw(
    path: str | Path, topics: Iterable[str] | None = None
) -> list[tuple[str, int, bytes, str]]:
    """Every message of ``topics`` (all when None) as (topic, time [ns], raw CDR, type name),
    after checking that the bag can be replayed here.

    Raises :class:`BagError`, naming the file and the problem, when the bag does not exist or
    does not open (metadata missing or of an unknown version), lacks a requested topic, holds
    a message type that is not installed or was recorded with another definition of it (an
    older version of a message: its bytes would be misread), or is truncated or corrupt.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    store = typestore()
    meta = p / "metadata.yaml" if p.is_dir() else p.with_name("metadata.yaml")
    if not meta.is_file():
        raise BagError(f"{p}: no metadata.yaml: not a rosbag2 bag, or an incomplete copy")
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        info["version"], info["relative_file_paths"]  # present, or KeyError
        reader = Reader(p)
    except (ReaderError, OSError, ValueError, KeyError, TypeError, yaml.YAMLError) as exc:
        raise BagError(f"{p}: metadata.yaml unreadable: {type(exc).__name__}: {exc}") from None
    try:
        reader.open()
    except (ReaderError, OSError, ValueError, KeyError, TypeError) as exc:
        where = "metadata.yaml" if "metadata" in str(exc).lower() else "a data file"
        raise BagError(f"{p}: {where} is truncated or corrupt: {exc}") from None
    try:
        have = {c.topic: c for c in reader.connections}
        wanted = None if topics is None else list(topics)
        if wanted is not None:
            missing = sorted(set(wanted) - set(have))
            if missing:
                raise BagError(
                    f"{p}: topic(s) {', '.join(missing)} not in the bag; it holds "
                    f"{', '.join(sorted(have)) or 'no topic'}"
                )
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for c in conns:
            _check_type(p, c, store)
        out: list[tuple[str, int, bytes, str]] = []
        try:
            for c, stamp, data in reader.messages(connections=conns):
                out.append((c.topic, stamp, bytes(data), c.msgtype))
        except Exception as exc:  # rosbags, mcap, zstd and sqlite3 each raise their own
            raise BagError(
                f"{p}: truncated or corrupt after {len(out)} messages ({type(exc).__name__}: {exc})"
            ) from None
        expected = sum(c.msgcount for c in conns)
        if expected and len(out) < expected:
            raise BagError(
                f"{p}: truncated: {len(out)} of the {expected} messages its metadata lists"
            )
        for c in conns:  # without a recorded type hash, the first message must decode
            if not c.digest.startswith("RIHS01_"):
                first = next((d for t, _, d, _ in out if t == c.topic), None)
                if first is not None:
                    _check_decodes(p, c, store, first)
        return out
    finally:
        reader.close()


def _check_type(p: Path, c: Any, store: Any) -> None:
    try:
        message_class(c.msgtype)
    except (ImportError, BagError):
        raise BagError(
            f"{p}: topic {c.topic} holds {c.msgtype}, a message type not installed here"
        ) from None
    if c.msgtype not in store.fielddefs:
        return
    ours = store.hash_rihs01(c.msgtype)
    if c.digest.startswith("RIHS01_") and c.digest != ours:
        raise BagError(
            f"{p}: topic {c.topic} was recorded with another definition of {c.msgtype} "
            f"(type hash {c.digest}, this build has {ours}): an older or newer version of the "
            "message, whose bytes this build would misread; re-record the bag, or convert it"
        )


def _check_decodes(p: Path, c: Any, store: Any, data: bytes) -> None:
    try:
        again = store.serialize_cdr(store.deserialize_cdr(data, c.msgtype), c.msgtype)
    except Exception as exc:
        again, why = None, f"{type(exc).__name__}: {exc}"
    else:
        why = "it re-encodes to other bytes"
    if again is None or bytes(again) != data:
        raise BagError(
            f"{p}: topic {c.topic}: its {c.msgtype} messages do not match this build's "
            f"definition ({why}): recorded by another version of the message?"
        )


class BagPlayer:
    """Publishes the raw CDR messages of a bag through rclpy, at the recorded pace.

    Args:
        node: the rclpy node that owns the publishers.
        path: the bag directory.
        topics: only these topics (all when None).
        rate: playback speed factor (1 = recorded pace); 0 publishes as fast as possible.
        remap: topic name → name to publish on.
    """

    def __init__(
        self,
        node: Any,
        path: str | Path,
        topics: Iterable[str] | None = None,
        rate: float = 1.0,
        remap: Mapping[str, str] | None = None,
    ) -> None:
        if rate < 0:
            raise BagError(f"rate {rate}: must be ≥ 0")
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        self._node = node
        self._rate = rate
        self._remap = dict(remap or {})
        raw = load_raw(self.path, topics)
        self._messages = [(topic, t, data) for topic, t, data, _ in raw]
        types = {topic: msgtype for topic, _, _, msgtype in raw}
        self._publishers = {
            topic: node.create_publisher(
                message_class(msgtype), self._remap.get(topic, topic), _qos(True)
            )
            for topic, msgtype in types.items()
        }
        self.published = 0

    @property
    def publishers(self) -> dict[str, Any]:
        """Topic (as recorded) → rclpy publisher."""
        return self._publishers

    def __len__(self) -> int:
        return len(self._messages)

    def play(self, stop: threading.Event | None = None) -> int:
        """Publish every message (blocking); returns how many were published."""
        if not self._messages:
            return 0
        t0_bag = self._messages[0][1]
        t0 = time.monotonic()
        for topic, stamp, data in self._messages:
            if stop is not None and stop.is_set():
                break
            if self._rate > 0:
                due = t0 + (stamp - t0_bag) * 1e-9 / self._rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            self._publishers[topic].publish(data)
            self.published += 1
        return self.published
