"""Peer libraries measured and tested beside ours, from a venv of their own (peer_venv): rotorpy as a plant and a
controller we did not write (rotorpy_peer)."""
