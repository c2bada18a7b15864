"""The learning problem: what a network sees and does, and how well it does it.

- encoding.py: goals -> network inputs, network outputs -> joint values within the limits;
- tree_encoding.py: the same for a tree of several end effectors, one block of inputs per effector;
- encodings.py: which of the two an arm takes (`encoding_for`, `encoding_from_dict`);
- controllers.py: the paper's MLP and NEAT's graphs as controllers goal -> q, their layout;
- kernels.py: the compiled, batched network + forward kinematics + error of a whole population;
- fitness.py: `Problem`, an arm with its fixed training and held-out goals and the fitness;
- checks.py: field checks shared by the settings dataclasses;
- environment.py: the LAB_* environment variables, read and checked (SettingError).

Nothing here knows which method trains the networks.
"""

from lab.problem.encoding import FEATURES, Encoding
from lab.problem.encodings import encoding_for, encoding_from_dict
from lab.problem.fitness import Problem, goal_errors

__all__ = ["FEATURES", "Encoding", "Problem", "encoding_for", "encoding_from_dict", "goal_errors"]
