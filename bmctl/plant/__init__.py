"""The paper's stochastic milling model as a seeded, vectorised simulator."""

from .kinematics import Kinematics, kinematics
from .plant import Plant, Record, default_card, make_plant

__all__ = ["Plant", "Record", "make_plant", "default_card", "kinematics", "Kinematics"]
