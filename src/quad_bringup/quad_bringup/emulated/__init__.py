"""The real-vehicle chain on one machine, for the bridge tests and the benches: the emulated autopilot, mavlink_bridge
and position_controller as processes (vehicle_graph), a mission through them (mission_flight), the same chain flown
offline (offline_chain) and a flight's twin checked (twin_check)."""
