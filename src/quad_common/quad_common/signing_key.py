"""A MAVLink 2 signing key file, read the same way by the bridge and the emulated vehicle (the key is shared
between both ends, so its file convention must be too)."""

import hashlib


def load_signing_key(path: str) -> bytes:
    """32-byte MAVLink 2 signing key from a file: 64 hex characters, else the SHA-256 of the file's text
    (MAVProxy's `signing setup PASSPHRASE` convention)."""
    with open(path, 'rb') as f:
        data = f.read().strip()
    if not data:
        raise ValueError(f'signing_key_file {path!r} is empty')
    try:
        key = bytes.fromhex(data.decode('ascii'))
        if len(key) == 32:
            return key
    except (ValueError, UnicodeDecodeError):
        pass
    return hashlib.sha256(data).digest()
