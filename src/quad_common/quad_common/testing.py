"""For tests: isolated ROS graphs (quad_common.domains, also what `quadflight fly` uses)."""

from quad_common.domains import FASTDDS_PROFILE, isolated_domain  # noqa: F401  (the tests' import path)
