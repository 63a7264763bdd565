"""Controllers that run against a plant (PID, MPC), each designed from a ``control.StateSpace``.

The PID and MPC arrive with the controller-design stage; the package exists now so that the
distribution's layout is stable.
"""

__all__: list[str] = []
