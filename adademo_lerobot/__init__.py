"""AdaDemo for LeRobot: grow imitation-learning datasets where the policy fails.

The paper's Algorithm 1 lives in :mod:`adademo_lerobot.algorithm`; suites, experts, strategies and samplers are
small classes behind the protocols in their folders.
"""

__version__ = "0.1.0"
