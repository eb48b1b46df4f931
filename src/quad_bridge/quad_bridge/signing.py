"""What MAVLink 2 signing tells about the link: the bridge's and the vehicle's keys disagreeing shows
as timeouts elsewhere (parameters not read, no heartbeat); this names signing instead. Counts from pymavlink's
MAVLinkSigning (sig_count: packets carrying a signature; badsig_count: signatures that failed our key) and the
packets refused as unsigned."""


def signing_problem(has_key: bool, signed_heard: int, bad_signatures: int, unsigned_refused: int) -> str:
    """Why the keys disagree, or ''."""
    if not has_key and signed_heard:
        return ('the vehicle signs its messages (MAVLink 2 signing) and signing_key_file is empty: a signing vehicle '
                'ignores unsigned commands; set signing_key_file to the vehicle\'s key')
    if has_key and bad_signatures:
        return (f'{bad_signatures} vehicle messages failed the MAVLink 2 signature check: signing_key_file is not '
                'the vehicle\'s key')
    if has_key and unsigned_refused:
        return (f'{unsigned_refused} unsigned messages refused (MAVLink 2 signing is on, signing_key_file): the '
                'vehicle does not sign; set the same key on it, or leave signing_key_file empty')
    return ''
