"""The flow step with an immersed circle (``FlowStep(immersed=(cx, cy, r))``,
diffphys_flow::immersed): what the keyword builds, the force it reports (the
forcing's momentum exchange), the gradient through the steps against central
differences, and the refusals."""

import numpy as np
import pytest

import diffphys as dp


def channel(**kw):
    """A channel 2 x 1, uniform inflow 1, a circle of radius 0.15 (1.2 cells)."""
    return dp.FlowStep((16, 8), (2.0, 1.0), sides="channel", inflow=1.0,
                       immersed=(0.6, 0.5, 0.15), viscosity=0.05, dt=0.02, **kw)


def start(scene):
    return np.full(scene.shape_x, 1.0), np.zeros(scene.shape_y)


def test_interiors_solid_and_forced():
    solid = channel()
    assert solid.solid.sum() == 4  # the cells whose centre lies in the circle
    forced = channel(immersed_interior="forced")
    assert not forced.solid.any()  # no solid cell: the faces inside are forced


@pytest.mark.parametrize("interior", ["solid", "forced"])
def test_the_immersed_body_feels_a_drag_and_no_lift(interior):
    scene = channel(immersed_interior=interior)
    _, _, _, force = scene.forward(*start(scene), steps=20)
    # flow in +x pushes the body in +x; the body is symmetric about y = 0.5
    assert force[0] > 0 and abs(force[1]) < 1e-9 * force[0]


def test_the_forced_interior_force_is_the_forcing_exchange_of_the_last_step():
    scene = channel(immersed_interior="forced")
    ux, uy = start(scene)
    a, b, p, _ = scene.forward(ux, uy, steps=9)
    _, _, _, one = scene.forward(a, b, pressure=p)
    _, _, _, ten = scene.forward(ux, uy, steps=10)
    np.testing.assert_allclose(ten, one, rtol=1e-12)


@pytest.mark.parametrize("interior,scheme", [("solid", "direct"), ("forced", "direct"),
                                             ("forced", "consistent")])
def test_gradients_through_the_steps_match_central_differences(interior, scheme):
    scene = channel(immersed_interior=interior, immersed_scheme=scheme)
    rng = np.random.default_rng(7)
    ux, uy = start(scene)
    ux = ux + 0.05 * rng.standard_normal(ux.shape)
    q = 1.0 + 0.1 * rng.standard_normal(scene.inflow_len)
    wx, wy = rng.standard_normal(scene.shape_x), rng.standard_normal(scene.shape_y)

    def loss(ux, q):
        vx, vy, _, _ = scene.forward(ux, uy, steps=6, inflow=q)
        return float(np.sum(wx * vx) + np.sum(wy * vy))

    g = scene.vjp(ux, uy, wx, wy, None, None, steps=6, inflow=q)
    h = 1e-6
    d = rng.standard_normal(ux.shape)
    fd = (loss(ux + h * d, q) - loss(ux - h * d, q)) / (2 * h)
    assert float(np.sum(g[0] * d)) == pytest.approx(fd, rel=1e-6)
    e = rng.standard_normal(q.shape)
    fd = (loss(ux, q + h * e) - loss(ux, q - h * e)) / (2 * h)
    assert float(g[5] @ e) == pytest.approx(fd, rel=1e-6)
    assert abs(fd) > 1e-3


def test_immersed_refusals():
    with pytest.raises(dp.InvalidArgumentError, match="immersed_interior"):
        channel(immersed_interior="hollow")
    with pytest.raises(dp.InvalidArgumentError, match="immersed_scheme"):
        channel(immersed_scheme="ghost")
    with pytest.raises(dp.InvalidArgumentError, match="not both"):
        channel(obstacle=np.zeros((16, 8), bool))
    with pytest.raises(dp.InvalidArgumentError, match="radius"):
        dp.FlowStep((16, 8), (2.0, 1.0), sides="channel", inflow=1.0, immersed=(0.6, 0.5, 0.0))
    scene = channel()
    with pytest.raises(dp.InvalidArgumentError, match="grad_force on an immersed circle"):
        scene.vjp(*start(scene), None, None, None, np.array([1.0, 0.0]), steps=2)
