"""rosbag2 recording core (no rclpy): serialized messages -> a rosbag2 bag with MCAP storage.

Written with the `rosbags` library; message definitions and type hashes come from its ROS 2
Jazzy typestore, so `ros2 bag info` / Foxglove / rosbags read the bag like one from `ros2 bag record`.

Crash safety: the MCAP writer keeps the open chunk in memory; `flush()` closes that chunk and
pushes it to the file, so a recorder killed with SIGKILL leaves every flushed chunk on disk but
no MCAP footer and no metadata.yaml. `repair_bag(path)` cuts a torn last record, appends the
footer and writes metadata.yaml from a scan of the file (in place: for a copy); `open_bag_reader` reads such a
bag from a repaired copy (`repaired_copy`: BAG.repaired next to it, else in the temp directory) and never
modifies its input; it says where the file was cut and where the copy is.
"""

import hashlib
import importlib.util
import os
import pickle
import shutil
import struct
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from quad_common import contract
from quad_common.paths import cache_dir

BAG_VERSION = 9
MCAP_MAGIC = b'\x89MCAP0\r\n'
_OP_FOOTER, _OP_DATA_END = 0x02, 0x0F


def typestore(*msgtypes: str) -> Typestore:
    """A ROS 2 Jazzy typestore (message definitions + RIHS01 hashes) holding `msgtypes` and every contract type.

    Where the contract's types are all that is asked for, a store of just those (CONTRACT_MSGTYPES and the types
    they use, 32) registered from their Jazzy definitions cached on disk (contract_fielddefs): 0.02 s of CPU,
    where building rosbags' whole Jazzy store (every distribution's modules, ~500 message classes) takes 0.13 s
    in each process that records or reads a bag. Otherwise that whole store. The definitions and hashes are
    the same either way; each store is built once per process."""
    global _CONTRACT_STORE, _FULL_STORE
    if _FULL_STORE is None:
        if _CONTRACT_STORE is None:
            fielddefs = contract_fielddefs()
            if fielddefs is not None:
                _CONTRACT_STORE = Typestore()
                _CONTRACT_STORE.register(fielddefs)
        if _CONTRACT_STORE is not None and all(t in _CONTRACT_STORE.types for t in msgtypes):
            return _CONTRACT_STORE
        _FULL_STORE = get_typestore(Stores.ROS2_JAZZY)
    return _FULL_STORE


_CONTRACT_STORE = _FULL_STORE = None
CONTRACT_MSGTYPES = tuple(sorted({t.msgtype for t in contract.TOPICS.values()}))


def contract_fielddefs() -> dict | None:
    """The Jazzy definitions of CONTRACT_MSGTYPES and of every type they use ({msgtype: (constants, fields)}): read
    from the cache (quad_common.paths.cache_dir, a file named by a digest of rosbags' store modules and of the
    types), else taken from the whole store and cached. None where neither is possible."""
    path = _contract_cache_path()
    try:
        with open(path, 'rb') as f:
            fielddefs = pickle.load(f)
        if isinstance(fielddefs, dict) and all(t in fielddefs for t in CONTRACT_MSGTYPES):
            return fielddefs
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError):
        pass
    global _FULL_STORE
    if _FULL_STORE is None:
        _FULL_STORE = get_typestore(Stores.ROS2_JAZZY)
    fielddefs = type_closure(_FULL_STORE, CONTRACT_MSGTYPES)
    if path is not None:
        try:   # written whole under another name, then renamed: a reader never sees a partial file
            with tempfile.NamedTemporaryFile('wb', dir=path.parent, prefix=path.name, delete=False) as f:
                pickle.dump(fielddefs, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(f.name, path)
        except OSError:
            pass
    return fielddefs


def type_closure(store: Typestore, msgtypes) -> dict:
    """{msgtype: store's (constants, fields)} of `msgtypes` and of every message type their fields use."""
    closure = {}
    pending = list(msgtypes)
    while pending:
        name = pending.pop()
        if name in closure:
            continue
        closure[name] = store.fielddefs[name]
        pending += [used for _, field in closure[name][1] for used in _used_types(field)
                    if used in store.fielddefs]
    return closure


def _used_types(node):
    """The type names in a field's parse tree (nested tuples of a Nodetype and its details)."""
    if isinstance(node, str):
        return [node]
    if isinstance(node, tuple):
        return [name for part in node for name in _used_types(part)]
    return []


def _contract_cache_path() -> Path | None:
    stores = Path(importlib.util.find_spec('rosbags.typesys.stores').origin).parent
    digest = hashlib.sha256(' '.join(CONTRACT_MSGTYPES).encode())
    for module in sorted(stores.glob('*.py')):
        stat = module.stat()
        digest.update(f'{module.name} {stat.st_size} {stat.st_mtime_ns}'.encode())
    try:
        return cache_dir() / f'rosbags-jazzy-contract-{digest.hexdigest()[:16]}.pickle'
    except OSError:
        return None


@dataclass(frozen=True)
class TopicSpec:
    """A topic to record: its type (ROS name, e.g. nav_msgs/msg/Odometry) and whether it is latched."""
    msgtype: str
    latched: bool = False


# The topics `quadflight fly` records: the contract's (quad_common.contract), but battery (the bridge's).
DEFAULT_TOPICS = {name: TopicSpec(t.msgtype, latched=t.latched) for name, t in contract.TOPICS.items()
                  if name != contract.BATTERY}


def contract_spec(topic: str) -> TopicSpec | None:
    """The contract's spec of `topic`: its own name ('odom'), or the contract topic a namespaced name ends with
    ('/cf1/odom', '/cf1/cmd/attitude_thrust': a fleet vehicle's); None for any other topic."""
    if topic in DEFAULT_TOPICS:
        return DEFAULT_TOPICS[topic]
    return DEFAULT_TOPICS.get(contract.contract_name(topic))


def installed(spec: TopicSpec) -> bool:
    """Whether the message package of `spec` can be imported here (tf2_msgs is not among the PyPI wheels)."""
    return importlib.util.find_spec(spec.msgtype.split('/')[0]) is not None


def offered_qos(latched: bool, depth: int) -> Qos:
    """The QoS profile stored with a connection (what `ros2 bag play` offers on replay)."""
    zero = QosTime(sec=0, nsec=0)
    return Qos(history=QosHistory.KEEP_LAST, depth=depth, reliability=QosReliability.RELIABLE,
               durability=QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
               deadline=zero, lifespan=zero, liveliness=QosLiveliness.AUTOMATIC,
               liveliness_lease_duration=zero, avoid_ros_namespace_conventions=False)


class BagRecorder:
    """Writes serialized (CDR) messages of named topics into a new rosbag2/MCAP bag at `path`.

    Topics may be added at any time; `counts[topic]` is the number written so far.
    """

    def __init__(self, path):
        self.path = Path(path)
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections = {}
        self.counts = {}
        self._sync_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix='bag-fsync')
        self._syncing = None   # the fsync in progress (a Future), if any

    def add_topic(self, topic: str, spec: TopicSpec, depth: int = 10):
        if topic in self._connections:
            return
        store = typestore(spec.msgtype)
        if spec.msgtype not in store.types:
            raise ValueError(f'topic {topic}: message type {spec.msgtype!r} is not in the ROS 2 Jazzy typestore')
        self._connections[topic] = self._writer.add_connection(
            topic, spec.msgtype, typestore=store, offered_qos_profiles=[offered_qos(spec.latched, depth)])
        self.counts[topic] = 0

    def write(self, topic: str, timestamp_ns: int, data: bytes):
        self._writer.write(self._connections[topic], int(timestamp_ns), data)
        self.counts[topic] += 1

    def flush(self):
        """Push the pending chunk to the file (so a SIGKILL loses at most what came after this: the kernel holds it),
        and to the disk in a thread of its own (os.fsync, for a crash of the machine): fsync waits for the disk, a
        tenth of a second and more beside another process's writes, and the writing thread is a lockstep follower
        that must not stop for it. One fsync at a time: a flush while one is still running leaves it to the next."""
        storage = self._writer.storage
        if storage is None:
            return
        if storage.chunk.bio.tell():
            storage.close_chunk()
        storage.bio.flush()
        if self._syncing is None or self._syncing.done():
            self._syncing = self._sync_thread.submit(os.fsync, storage.bio.fileno())

    def close(self):
        """Finish the MCAP file (index, footer) and write metadata.yaml (after the fsync in progress: it holds
        the file's descriptor)."""
        self._sync_thread.shutdown(wait=True)
        if self._writer.storage is not None:
            self._writer.close()

    @property
    def total(self) -> int:
        return sum(self.counts.values())


# --- reading, and repairing a bag whose recorder was killed ---------------------------------

def _mcap_file(bag_dir: Path) -> Path | None:
    files = sorted(bag_dir.glob('*.mcap'))
    return files[0] if len(files) == 1 else None


def _has_footer(mcap: Path) -> bool:
    size = mcap.stat().st_size
    if size < 8 + 37:
        return False
    with mcap.open('rb') as f:
        f.seek(-37, os.SEEK_END)
        tail = f.read()
    return tail[-8:] == MCAP_MAGIC and tail[0] == _OP_FOOTER


def _last_whole_record_end(mcap: Path) -> int:
    """Byte offset after the last complete top-level record (header and chunks of a torn file)."""
    with mcap.open('rb') as f:
        data = f.read()
    if not data.startswith(MCAP_MAGIC):
        raise ValueError(f'{mcap}: not an MCAP file (bad magic)')
    pos = end = len(MCAP_MAGIC)
    while pos + 9 <= len(data):
        op = data[pos]
        (length,) = struct.unpack_from('<Q', data, pos + 1)
        nxt = pos + 9 + length
        if nxt > len(data) or op in (_OP_FOOTER, _OP_DATA_END):
            break
        pos = end = nxt
    return end


def needs_repair(bag_dir) -> bool:
    """A single .mcap without its footer or without metadata.yaml: a recorder that did not close its bag."""
    bag_dir = Path(bag_dir)
    mcap = _mcap_file(bag_dir)
    return mcap is not None and not ((bag_dir / 'metadata.yaml').exists() and _has_footer(mcap))


def repair_bag(bag_dir) -> int | None:
    """Make the bag of a killed recorder readable IN PLACE (use it on a copy): returns the byte offset the .mcap
    was cut at (its size if nothing was torn), or None if it needed no repair.

    Keeps every whole record (all flushed chunks), appends DataEnd + a footer without summary
    (readers then scan the file) and writes metadata.yaml with the counts found by that scan.
    """
    bag_dir = Path(bag_dir)
    if not needs_repair(bag_dir):
        return None
    mcap = _mcap_file(bag_dir)
    end = mcap.stat().st_size
    if not _has_footer(mcap):
        end = _last_whole_record_end(mcap)
        with mcap.open('r+b') as f:
            f.truncate(end)
            f.seek(end)
            f.write(bytes([_OP_DATA_END]) + struct.pack('<QI', 4, 0))
            f.write(bytes([_OP_FOOTER]) + struct.pack('<QQQI', 20, 0, 0, 0) + MCAP_MAGIC)
    _write_metadata(bag_dir, mcap)
    return end


@dataclass
class Repair:
    """Where a bag left by a killed recorder was cut, and where its repaired copy is."""
    file: str
    size_bytes: int
    cut_at_byte: int
    repaired_copy: str

    def as_dict(self) -> dict:
        return asdict(self)


def repaired_copy(bag_dir) -> Repair:
    """Copy the bag to BAG.repaired next to it (the temp directory if that is not writable) and repair the copy.
    A copy made from the same file (same size and mtime, noted in it) is reused."""
    bag_dir = Path(bag_dir)
    mcap = _mcap_file(bag_dir)
    st = mcap.stat()
    source = f'{mcap.resolve()} {st.st_size} {st.st_mtime_ns}\n'
    for parent in (bag_dir.parent, Path(tempfile.gettempdir())):
        copy = parent / f'{bag_dir.name}.repaired'
        marker = copy / 'repaired_from.txt'
        try:
            if marker.is_file() and marker.read_text() == source:
                return Repair(str(mcap), st.st_size, int(marker.with_name('cut_at.txt').read_text()), str(copy))
            staging = Path(tempfile.mkdtemp(prefix=f'.{bag_dir.name}.repairing-', dir=parent))
        except OSError:
            continue
        try:
            shutil.copy2(mcap, staging / mcap.name)
            cut = repair_bag(staging)
            (staging / 'cut_at.txt').write_text(str(cut))
            (staging / 'repaired_from.txt').write_text(source)
            if copy.exists():
                shutil.rmtree(copy)
            staging.rename(copy)
        except OSError:
            shutil.rmtree(staging, ignore_errors=True)
            continue
        return Repair(str(mcap), st.st_size, cut, str(copy))
    raise OSError(f'bag {bag_dir}: needs repair, and no writable place for a repaired copy')


def _write_metadata(bag_dir: Path, mcap: Path):
    import yaml
    from rosbags.rosbag2.metadata import dump_qos_v9

    storage = McapReader(mcap)
    storage.open()
    try:
        meta = storage.metadata
        count = meta.message_count
        start = meta.start_time if count else 0
        duration = meta.duration - 1 if count else 0
        store = typestore(*(c.msgtype for c in storage.connections))
        topics = [{
            'topic_metadata': {
                'name': c.topic, 'type': c.msgtype, 'serialization_format': 'cdr',
                'offered_qos_profiles': dump_qos_v9(list(c.ext.offered_qos_profiles)),
                'type_description_hash': store.hash_rihs01(c.msgtype) if c.msgtype in store.types else ''},
            'message_count': c.msgcount} for c in storage.connections]
    finally:
        storage.close()
    info = {
        'version': BAG_VERSION, 'storage_identifier': 'mcap', 'relative_file_paths': [mcap.name],
        'duration': {'nanoseconds': duration}, 'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count, 'topics_with_message_count': topics,
        'compression_format': '', 'compression_mode': '',
        'files': [{'path': mcap.name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': {'repaired': 'recorder did not close the bag; recovered up to its last flushed chunk'},
        'ros_distro': 'rosbags',
    }
    with (bag_dir / 'metadata.yaml').open('w') as f:
        yaml.safe_dump({'rosbag2_bagfile_information': info}, f, default_flow_style=False, sort_keys=False)


def open_bag_reader(bag_dir) -> tuple[Reader, Repair | None]:
    """(an opened rosbags Reader, None), or for a bag left by a killed recorder (a reader of its repaired copy,
    the Repair saying where it was cut and where the copy is). The input is never modified."""
    from quad_bringup.checks.inputs import check_bag_dir

    bag_dir = Path(bag_dir)
    check_bag_dir(bag_dir)
    repair = None
    if needs_repair(bag_dir):
        repair = repaired_copy(bag_dir)
        bag_dir = Path(repair.repaired_copy)
    if not (bag_dir / 'metadata.yaml').exists():
        raise FileNotFoundError(f'bag {bag_dir}: no metadata.yaml and no single .mcap file to recover it from')
    reader = Reader(bag_dir)
    reader.open()
    return reader, repair
