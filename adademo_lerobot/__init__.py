"""AdaDemo for LeRobot: grow imitation-learning datasets where the policy fails.

The paper's Algorithm 1 lives in :mod:`adademo_lerobot.strategies.algorithm`; suites, experts, strategies and samplers are
small classes behind the protocols in their folders. Importing the package is cheap and changes nothing of the
process: it checks the Python and LeRobot versions; torch, LeRobot and the simulators are imported where used.
The commands (and LeRobot's import of our plugins) pick a GL backend that loads before MuJoCo is imported; a
program that renders camera images with the library calls `adademo_lerobot.core.gl.prefer_loadable_backend()` first.
"""

from adademo_lerobot.core.versions import check_supported_versions

__version__ = "0.3.0.dev0"

check_supported_versions()
