"""diagnostic_msgs helpers: every node reports on `diagnostics` the same way."""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)


def status(name: str, level, message: str, values: dict | None = None, hardware_id='') -> DiagnosticStatus:
    """level: OK/WARN/ERROR/STALE above (bytes, as the message defines them) or an int."""
    level = level if isinstance(level, (bytes, bytearray)) else bytes([level])
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=str(v)) for k, v in (values or {}).items()])


def array(stamp, statuses) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(statuses)
    return msg


def level_of(st: DiagnosticStatus) -> int:
    return st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
