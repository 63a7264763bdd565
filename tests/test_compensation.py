"""controllers.compensation: the input equivalent of an identified effect, against hand-computed answers, in a loop
with a nonlinear model (the compensated loop settles where the linear design predicts), JSON files, bad input."""

import math

import numpy as np
import pytest

from controllers.base import controller_kinds, load_controller
from controllers.compensation import EffectCompensation, effect_terms
from controllers.pid import PID
from cosim.errors import InvalidSettingError
from cosim.identify.model import IdentifiedModel
from cosim.loop.closed_loop import ModelPlant

# a mass with viscous and Coulomb friction: v' = -2 v + 0.5 u - 0.25 tanh(v/0.001), i.e. Fc = 0.5 in units of u
FRICTION = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u", "tanh(v/0.001)"),
                           coef=np.array([[1.0, 0.0, 0.0], [-2.0, 0.5, -0.25]]))


def speed_pid(**options):
    return PID(kp=4.0, dt=0.01, inputs="u", outputs="v", **options)


def settle(controller, model, setpoint=1.0, steps=3000):
    plant = ModelPlant(model, dt=0.01, inputs=["u"], outputs=["x", "v"])
    controller.reset()
    controller.setpoint = setpoint
    y = plant.read_outputs()
    names = ["x", "v"]
    for k in range(steps):
        u = controller(0.01 * k, [y[names.index(n)] for n in controller.outputs])
        y = plant.step(u)
    return y


def test_linear_part_and_effect_terms():
    linear = FRICTION.linear_part()
    assert linear.is_linear and linear.terms == ("v", "u")
    np.testing.assert_array_equal(linear.coef, [[1.0, 0.0], [-2.0, 0.5]])
    terms, coef = effect_terms(FRICTION)
    assert terms == ("tanh(v/0.001)",)
    np.testing.assert_array_equal(coef, [[0.0], [-0.25]])


def test_the_gain_is_the_friction_force_and_cancels_the_term():
    ctrl = EffectCompensation.from_model(speed_pid(), FRICTION)
    assert ctrl.gains.tolist() == [[0.5]]  # -(-0.25)/0.5: Fc in units of the input
    assert ctrl.info["compensated_rows"] == ["v"] and ctrl.info["uncancelled_fraction"] == 0.0
    ctrl.setpoint = 1.0
    u = ctrl(0.0, [0.3])[0]
    assert u == pytest.approx(4.0 * 0.7 + 0.5 * math.tanh(300.0))
    assert ctrl.compensation.tolist() == pytest.approx([0.5 * math.tanh(300.0)])


def test_compensated_loop_settles_where_the_linear_design_predicts():
    # P control of v' = -2 v + 0.5 u: v = 0.5*4 / (2 + 0.5*4) = 0.5. Friction pulls it to (2 - 0.25)/4 = 0.4375;
    # the compensation gives back the linear answer.
    alone = settle(speed_pid(), FRICTION)[1]
    compensated = settle(EffectCompensation.from_model(speed_pid(), FRICTION), FRICTION)[1]
    linear = settle(speed_pid(), FRICTION.linear_part())[1]
    assert alone == pytest.approx(0.4375, abs=1e-6)
    assert linear == pytest.approx(0.5, abs=1e-9)
    assert compensated == pytest.approx(0.5, abs=1e-9)


def test_limits_hold_for_the_sum():
    ctrl = EffectCompensation.from_model(speed_pid(u_min=-1.0, u_max=1.0, du_max=0.2), FRICTION)
    ctrl.setpoint = 10.0
    first, second = ctrl(0.0, [0.5])[0], ctrl(0.01, [0.5])[0]
    assert first == 1.0 and second == 1.0  # P alone saturates; the compensation may not push past the limit
    ctrl.reset()
    ctrl.setpoint = -10.0
    assert ctrl(0.0, [0.5])[0] == pytest.approx(-1.0 + 0.5)  # inner at its limit, compensation on top
    assert ctrl(0.01, [-0.5])[0] == pytest.approx(-0.5 - 0.2)  # -1.5 wanted: the rate limit holds the sum
    assert ctrl(0.02, [-0.5])[0] == pytest.approx(-0.9)
    assert ctrl(0.03, [-0.5])[0] == -1.0


def test_it_measures_what_the_terms_need_and_forwards_the_setpoint():
    inner = PID(kp=1.0, dt=0.01, inputs="u", outputs="x")  # a position loop that does not measure v
    ctrl = EffectCompensation.from_model(inner, FRICTION)
    assert ctrl.outputs == ("x", "v") and ctrl.tracked == ("x",)
    ctrl.setpoint = 2.0
    assert inner.setpoint.tolist() == [2.0]
    assert ctrl(0.0, [0.0, -1.0])[0] == pytest.approx(2.0 - 0.5 * math.tanh(1000.0))
    with pytest.raises(InvalidSettingError, match="measures"):
        ctrl(0.0, [0.0])


def test_json_round_trip(tmp_path):
    assert "compensation" in controller_kinds()
    ctrl = EffectCompensation.from_model(speed_pid(u_min=-3, u_max=3), FRICTION)
    path = ctrl.save(tmp_path / "c.json")
    back = load_controller(path)
    assert isinstance(back, EffectCompensation) and isinstance(back.inner, PID)
    assert back.terms == ctrl.terms and back.gains.tolist() == ctrl.gains.tolist()
    assert back.info["compensated_rows"] == ["v"]
    for c in (ctrl, back):
        c.reset()
        c.setpoint = 1.0
    ys = [0.0, 0.2, -0.001, 0.0004, 0.9]
    assert [back(0.01 * k, [y])[0] for k, y in enumerate(ys)] == [ctrl(0.01 * k, [y])[0] for k, y in enumerate(ys)]


def test_bad_input_is_refused():
    with pytest.raises(InvalidSettingError, match="no nonlinear term"):
        EffectCompensation.from_model(speed_pid(), FRICTION.linear_part())
    load_side = IdentifiedModel(states=("x", "v"), inputs=("u",), terms=("v", "u", "tanh(x/0.001)"),
                                coef=np.array([[1.0, 0.0, -0.3], [-2.0, 0.5, 0.0]]))
    with pytest.raises(InvalidSettingError, match="no manipulated input acts on"):
        EffectCompensation.from_model(speed_pid(), load_side)
    with pytest.raises(InvalidSettingError, match="manipulated input"):
        EffectCompensation(speed_pid(), terms=["tanh(u/10)"], gains=[[1.0]])
    with pytest.raises(InvalidSettingError, match="gains"):
        EffectCompensation(speed_pid(), terms=["tanh(v/0.001)"], gains=[[1.0, 2.0]])
    with pytest.raises(InvalidSettingError, match="not an input of the model"):
        EffectCompensation.from_model(PID(kp=1.0, dt=0.01, inputs="w", outputs="v"), FRICTION)
