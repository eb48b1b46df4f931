"""The geofence box (map, ENU): leaving it while armed ends the hand-over and lands, once until reset."""

import numpy as np


class Geofence:
    def __init__(self, enabled: bool, min_m, max_m):
        self.enabled = enabled
        self.min_m, self.max_m = np.asarray(min_m, float), np.asarray(max_m, float)
        self.breached = False

    def check(self, position, armed: bool) -> bool:
        """True once, when an armed vehicle is first seen outside the box."""
        if not self.enabled or self.breached or not armed:
            return False
        if np.all(position >= self.min_m) and np.all(position <= self.max_m):
            return False
        self.breached = True
        return True

    def reset(self):
        """`offboard` re-enables it."""
        self.breached = False
