"""python -m quad_sim.compile_kernels: every physics kernel compiled into numba's cache now, or loaded where the cache
has it already (quad_common.compiled).

`make kernels` (the first step of `make test`) runs it for each folder the packages are imported from: numba keeps a
kernel's machine code per source folder, and there are two (the build's, which the installed nodes import; src/,
which `./quadflight` and the package tests import). Without it, a fresh clone's first processes (a test run's, every
run on a new CI machine) compile the kernels while their flights wait: ~12 s of CPU each on the 2-core machine, at
load ~9 long enough for a test's 90 s wait for an emulated vehicle to run out."""

import numpy as np

from quad_common.paths import resolve_config
from quad_common.vehicle import load_vehicle
from quad_sim.parameters import SPECS
from quad_sim.simulator import Simulator
from quad_sim.vehicle_contact import closest_approach

DEFAULT_VEHICLE = next(spec.default for spec in SPECS if spec.name == 'vehicle')


def main():
    """The simulator's kernels (Simulator.warm_up: a step of the physics and of its autopilot) and a fleet's contact
    check."""
    Simulator(load_vehicle(resolve_config(DEFAULT_VEHICLE))).warm_up()
    closest_approach(np.zeros((2, 3)), np.ones((2, 3)), [0], [1])


if __name__ == '__main__':
    main()
