"""Physics shared by the plant and the moment model: kinematics (Burgio), the impact laws and
hit rate, the thermal and hardening laws, and the named constants. Neither
:mod:`bmctl.plant` nor :mod:`bmctl.moments` is needed to use it.
"""
