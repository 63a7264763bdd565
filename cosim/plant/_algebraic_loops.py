"""Algebraic loops between FMUs, solved at each communication point, for
:class:`~cosim.plant.system_plant.SystemPlant`.

A loop is a cycle of connections each reaching an output that depends directly on it
(:func:`cosim.plant.system_wiring.wire` finds them). Its components form a block; the unknowns are the values of
the connections inside the block. For values ``z`` the block's components are given their inputs (``z`` where a
block connection drives them, the newest values elsewhere) and their outputs read; the connections then carry
``G(z)``, and the loop is solved where ``z = G(z)``, by Newton's method on a finite-difference Jacobian, to a
residual of :data:`TOLERANCE` relative.

Each trial sets inputs on the FMUs. So that no trial leaves a trace (an FMU may count or filter what it is given),
every component of the block saves its state before the iteration and restores it before each trial and before
the final set: which the FMUs must be able to do (``canGetAndSetFMUstate``). Where one cannot, the system is
refused in one line that names the loop's connectors (:func:`blocks`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InvalidSettingError

if TYPE_CHECKING:
    from .system_plant import SystemPlant

__all__ = ["LoopBlock", "blocks", "solve"]

#: The loop's residual ``|G(z) - z|`` the solution reaches, relative to ``1 + |z|``.
TOLERANCE = 1e-13
#: Newton iterations at most.
MAX_ITERATIONS = 30


@dataclass(frozen=True)
class LoopBlock:
    """Components joined by algebraic loops, and the connections inside them: (end component, its input's
    position, source component, output position, factor, offset)."""

    components: tuple[str, ...]
    links: tuple[tuple[str, int, str, int, float, float], ...]
    names: tuple[str, ...]  # the connections' ends, component.input, for messages


def blocks(plant: SystemPlant) -> list[LoopBlock]:
    """The system's loop blocks (loops sharing a component are one block); InvalidSettingError where a component
    of a loop cannot save and restore its state."""
    groups: list[set[str]] = []
    for loop in plant.wiring.loops:
        comps = {c for c in plant.system.components if any(n.startswith(c + ".") for n in loop)}
        joined = [g for g in groups if g & comps]
        for g in joined:
            groups.remove(g)
            comps |= g
        groups.append(comps)
    out = []
    for group in groups:
        for name in sorted(group):
            md = plant.wiring.descriptions[name]
            interface = md.coSimulation if plant.wiring.kinds[name] == "cs" else md.modelExchange
            if not getattr(interface, "canGetAndSetFMUstate", False):
                loop = next(x for x in plant.wiring.loops if any(n.startswith(name + ".") for n in x))
                raise InvalidSettingError(
                    f"algebraic loop through direct feedthrough: {' -> '.join((*loop, loop[0]))}; component {name} "
                    f"({plant.system.components[name].source.name}) cannot save and restore its state "
                    "(canGetAndSetFMUstate is false), so the master cannot iterate the loop: re-export it with that "
                    "capability, or break the loop with a component whose output does not answer its input at once")
        order = tuple(n for n in plant.wiring.order if n in group)
        links, names = [], []
        for n in order:
            for position, src in enumerate(plant._sources[n]):
                if src[0] == "link" and src[1] in group:
                    links.append((n, position, src[1], src[2], src[3], src[4]))
                    names.append(f"{n}.{plant._ins[n][position]}")
        out.append(LoopBlock(order, tuple(links), tuple(names)))
    return out


def _save(plant: SystemPlant, block: LoopBlock) -> dict[str, Any]:
    states = {}
    for n in block.components:
        fmu = plant.components[n]._fmu
        states[n] = fmu.getFMUstate() if plant.components[n].fmi_version == "2.0" else fmu.getFMUState()
    return states


def _restore(plant: SystemPlant, states: dict[str, Any], verb: str = "set") -> None:
    """Each component back to its saved state (`verb` ``"set"``), or the saved states freed (``"free"``)."""
    for n, state in states.items():
        v2 = plant.components[n].fmi_version == "2.0"
        getattr(plant.components[n]._fmu, f"{verb}FMUstate" if v2 else f"{verb}FMUState")(state)


def solve(plant: SystemPlant, block: LoopBlock, u_free: np.ndarray) -> int:
    """Solve the block's loop at the present communication point; leaves its components with the consistent
    inputs set and their outputs read into the master. Returns the Newton iterations taken."""
    states = _save(plant, block)
    try:
        def evaluate(z: np.ndarray) -> np.ndarray:
            _restore(plant, states)
            given = {(lk[0], lk[1]): float(v) for lk, v in zip(block.links, z, strict=True)}
            for n in block.components:
                values = plant._input_values(n, u_free, 0.0, 0.0, at_end=True)
                for position in range(len(values)):
                    if (n, position) in given:
                        values[position] = given[(n, position)]
                component = plant.components[n]
                component.set_inputs(values)
                plant._y[n][:] = component.read_outputs()
            return np.array([f * plant._y[src][i] + o for _, _, src, i, f, o in block.links])

        z = np.array([plant._input_values(n, u_free, 0.0, 0.0, at_end=True)[position]
                      for n, position, *_ in block.links])
        for iteration in range(1, MAX_ITERATIONS + 1):
            g = evaluate(z)
            r = g - z
            if np.max(np.abs(r) / (1.0 + np.abs(z))) <= TOLERANCE:
                return iteration
            jacobian = np.empty((z.size, z.size))
            for j in range(z.size):
                dz = 1e-7 * (1.0 + abs(z[j]))
                zj = z.copy()
                zj[j] += dz
                jacobian[:, j] = (evaluate(zj) - g) / dz
            try:
                z = z - np.linalg.solve(jacobian - np.eye(z.size), r)
            except np.linalg.LinAlgError:
                raise InvalidSettingError(f"the algebraic loop through {', '.join(block.names)} has no unique "
                                          "solution here (its Jacobian is singular)") from None
        raise InvalidSettingError(f"the algebraic loop through {', '.join(block.names)} did not converge in "
                                  f"{MAX_ITERATIONS} Newton iterations at t={plant.time:.9g} s")
    finally:
        _restore(plant, states, "free")
