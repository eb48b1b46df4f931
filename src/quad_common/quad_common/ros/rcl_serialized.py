"""Serialized messages through rcl's own C functions (ctypes on the libraries rclpy has loaded), for what rclpy
7.1.5 does not do: a take that returns the publisher's GID (SerializedTake), and a publish that lets the other
threads of the process run while the DDS write is under way (SerializedPublisher).

Why the publish: rclpy's `publish` calls `rcl_publish` with the interpreter lock held, so a DDS write that blocks
(Fast DDS waits up to the writer's max_blocking_time when its history is full, and longer stalls were seen) stops
every Python thread of the process for as long: in the bridge, the setpoint stream and the keep-alive too. A
function of a `ctypes.CDLL` is called with the lock released. Layouts: rmw 7.3 / rcutils 6.7 (Jazzy)."""

import ctypes

from rclpy.serialization import serialize_message

RMW_GID_STORAGE_SIZE = 16
RCL_RET_OK = 0


class _Gid(ctypes.Structure):   # rmw/types.h rmw_gid_t
    _fields_ = [('implementation_identifier', ctypes.c_char_p), ('data', ctypes.c_uint8 * RMW_GID_STORAGE_SIZE)]


class _MessageInfo(ctypes.Structure):   # rmw/types.h rmw_message_info_t
    _fields_ = [('source_timestamp', ctypes.c_int64), ('received_timestamp', ctypes.c_int64),
                ('publication_sequence_number', ctypes.c_uint64), ('reception_sequence_number', ctypes.c_uint64),
                ('publisher_gid', _Gid), ('from_intra_process', ctypes.c_bool)]


class _Allocator(ctypes.Structure):     # rcutils/allocator.h rcutils_allocator_t
    _fields_ = [('allocate', ctypes.c_void_p), ('deallocate', ctypes.c_void_p), ('reallocate', ctypes.c_void_p),
                ('zero_allocate', ctypes.c_void_p), ('state', ctypes.c_void_p)]


class _SerializedMessage(ctypes.Structure):   # rcutils_uint8_array_t
    _fields_ = [('buffer', ctypes.POINTER(ctypes.c_uint8)), ('buffer_length', ctypes.c_size_t),
                ('buffer_capacity', ctypes.c_size_t), ('allocator', _Allocator)]


class _ErrorString(ctypes.Structure):   # rcutils/error_handling.h rcutils_error_string_t
    _fields_ = [('str', ctypes.c_char * 1024)]


_libraries = {}


def _library(name: str) -> ctypes.CDLL:
    if name not in _libraries:
        _libraries[name] = ctypes.CDLL(name)
    return _libraries[name]


def _take_error() -> str:
    """rcl's error message of this thread, then cleared (as rclpy does after a failed call)."""
    rcutils = _library('librcutils.so')
    rcutils.rcutils_get_error_string.restype = _ErrorString
    text = rcutils.rcutils_get_error_string().str.decode(errors='replace')
    rcutils.rcutils_reset_error()
    return text


class SerializedTake:
    """take(subscription) -> (CDR bytes, publisher gid bytes) or None: rcl_take_serialized_message on the
    subscription's rcl handle, one reusable buffer. One thread at a time."""

    def __init__(self, capacity: int = 1024):
        self._rcl, self._rcutils = _library('librcl.so'), _library('librcutils.so')
        self._rcl.rcl_take_serialized_message.argtypes = [ctypes.c_void_p] * 4
        self._rcutils.rcutils_get_default_allocator.restype = _Allocator
        self._allocator = self._rcutils.rcutils_get_default_allocator()
        self._message = _SerializedMessage()
        self._info = _MessageInfo()
        if self._rcutils.rcutils_uint8_array_init(ctypes.byref(self._message), ctypes.c_size_t(capacity),
                                                  ctypes.byref(self._allocator)) != RCL_RET_OK:
            raise MemoryError('rcutils_uint8_array_init failed')
        # made once: every setpoint is taken through here
        self._take_c = self._rcl.rcl_take_serialized_message
        self._message_ref, self._info_ref = ctypes.byref(self._message), ctypes.byref(self._info)
        self._gid_address = ctypes.addressof(self._info) + _MessageInfo.publisher_gid.offset + _Gid.data.offset

    def __call__(self, subscription):
        handle = subscription.handle
        with handle:
            ret = self._take_c(handle.pointer, self._message_ref, self._info_ref, None)
        if ret != RCL_RET_OK:   # RCL_RET_SUBSCRIPTION_TAKE_FAILED: nothing there after all
            return None
        message = self._message
        return (ctypes.string_at(message.buffer, message.buffer_length),
                ctypes.string_at(self._gid_address, RMW_GID_STORAGE_SIZE))

    def close(self):
        if self._message.buffer:
            self._rcutils.rcutils_uint8_array_fini(ctypes.byref(self._message))
            self._message.buffer = None


class SerializedPublisher:
    """publish(message or its CDR bytes) on an rclpy publisher through rcl_publish_serialized_message, the
    interpreter lock released during the write (bytes are written where they lie; a message is serialized first,
    with the lock held: CPU only). Any number of threads; a failed write raises RuntimeError with rcl's message,
    as rclpy's publish raises its RCLError."""

    def __init__(self, publisher):
        self.publisher = publisher
        rcl = _library('librcl.so')
        self._publish_c = rcl.rcl_publish_serialized_message
        self._publish_c.argtypes = [ctypes.c_void_p, ctypes.POINTER(_SerializedMessage), ctypes.c_void_p]
        self._publish_c.restype = ctypes.c_int

    def publish(self, data):
        if not isinstance(data, bytes):
            data = serialize_message(data)
        message = _SerializedMessage()
        message.buffer = ctypes.cast(ctypes.c_char_p(data), ctypes.POINTER(ctypes.c_uint8))
        message.buffer_length = message.buffer_capacity = len(data)
        handle = self.publisher.handle
        with handle:
            ret = self._publish_c(handle.pointer, ctypes.byref(message), None)
        if ret != RCL_RET_OK:
            raise RuntimeError(f'publish on {self.publisher.topic_name} failed ({ret}): {_take_error()}')
