"""AdaDemo for LeRobot: grow imitation-learning datasets where the policy fails.

The paper's Algorithm 1 lives in :mod:`adademo_lerobot.algorithm`; suites, experts, strategies and samplers are
small classes behind the protocols in their folders. Importing the package is cheap: it checks the Python and
LeRobot versions and picks a GL backend that loads; torch, LeRobot and the simulators are imported where used.
"""

from adademo_lerobot.gl import prefer_loadable_backend
from adademo_lerobot.versions import check_supported_versions

__version__ = "0.2.0"

check_supported_versions()
prefer_loadable_backend()
