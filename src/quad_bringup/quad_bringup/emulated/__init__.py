"""The real-vehicle chain on one machine, for the bridge tests and the benches: the emulated autopilot, mavlink_bridge
and position_controller as processes (emulated_graph), a mission through them (emulated_mission), the same chain flown
offline (emulated_chain) and a flight's twin checked (emulated_twin)."""
