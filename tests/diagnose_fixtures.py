"""Shared by the diagnosis input tests: a mass-spring-damper model, a record of it, CSV writing, and the check
that a CLI error is one line that says what to do."""

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
