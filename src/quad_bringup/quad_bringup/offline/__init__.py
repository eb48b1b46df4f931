"""Flights without ROS: the one closed loop (harness), a mission flown through it, a fleet in lockstep, a flight's twin
(replay) and a profile's margin on an autopilot (stability)."""
