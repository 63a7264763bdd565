"""Shared by the diagnosis tests: a mass-spring-damper model, a record of it, CSV writing, the check that a CLI
error is one line that says what to do, and a noise-free mass with Coulomb friction with the linear model it
lacks the friction in (:func:`coulomb_mass`)."""

from __future__ import annotations

import numpy as np

from cosim.identify.model import IdentifiedModel

K, C, DT = 20.0, 3.0, 1e-3
MODEL = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "x", "u"),
                        coef=np.array([[1.0, 0.0, 0.0], [-C, -K, 1.0]]))


def record(n: int, constant: bool = False, coulomb: float = 0.0) -> dict[str, np.ndarray]:
    """A mass-spring-damper (the model above, exactly, plus a Coulomb friction ``coulomb*sign(v)`` the model
    lacks) driven by a sine plus a square wave, Euler at DT."""
    t = np.arange(n) * DT
    u = np.ones(n) if constant else 3 * np.sin(2 * np.pi * 1.3 * t) + 1.5 * np.sign(np.sin(2 * np.pi * 0.7 * t))
    x, v = np.zeros(n), np.zeros(n)
    for k in range(n - 1):
        x[k + 1], v[k + 1] = x[k] + DT * v[k], v[k] + DT * (u[k] - C * v[k] - K * x[k] - coulomb * np.sign(v[k]))
    return {"t": t, "x": x, "v": v, "u": u}


def write_csv(path, columns: dict[str, np.ndarray]):
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=",", header=",".join(columns), comments="")
    return path


def assert_one_line_error(result, *fragments: str) -> None:
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    assert result.stdout == ""


def coulomb_mass():
    """A noise-free mass with viscous (2 N s/m) and Coulomb friction (1 N, tanh over 1 mm/s) under a sine plus a
    square wave, 3 s at 1 kHz (ten Euler substeps a sample), and the linear model without the Coulomb friction:
    (trajectory, model). The diagnosis of the one with the other is quick, and its evidence shows the step."""
    from cosim.data.trajectory import Trajectory

    dt, n = 1e-3, 3000
    t = np.arange(n + 1) * dt
    u = 3.0 * np.sin(2 * np.pi * 1.3 * t) + 1.5 * np.sign(np.sin(2 * np.pi * 0.7 * t))
    x, v = np.zeros(n + 1), np.zeros(n + 1)
    for k in range(n):
        xs, vs = x[k], v[k]
        for _ in range(10):
            xs, vs = xs + 1e-4 * vs, vs + 1e-4 * (u[k] - 2.0 * vs - 1.0 * np.tanh(vs / 1e-3))
        x[k + 1], v[k + 1] = xs, vs
    data = Trajectory.from_arrays(t, {"x": x, "v": v, "u": u}, units={"x": "m", "v": "m/s", "u": "N"},
                                  roles={"x": "state", "v": "state", "u": "input"})
    linear = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u"),
                             coef=np.array([[1.0, 0.0], [-2.0, 1.0]]))
    return data, linear
