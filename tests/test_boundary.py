"""Walls and obstacles (mrsph/sph/boundary.py): the projection out of a box never goes
through a face that lies on the domain's wall.

A post standing on the floor has its bottom face on the floor. A particle pushed into
the post near the floor was projected through that face, onto the floor inside the
post's footprint: a slot of no width from which nothing pushed it out, where particles
piled up on their own images until the pressure crushing them threw them across the tank
(the stirred pbf demo at 633 m/s, docs/validation.md, "Stirred soak").
"""

from types import SimpleNamespace

import numpy as np
import pytest
import taichi as ti

from mrsph.sph.boundary import Boundary, shut_faces


def _boundary(dim, box_min, box_max):
    lo, hi = [0.0] * dim, [1.6, 0.8, 0.4][:dim]
    domain = SimpleNamespace(min=lo, max=hi, restitution=0.0, friction=0.0)
    box = SimpleNamespace(shape="box", min=list(box_min), max=list(box_max))
    return Boundary(dim, domain, [box])


def _collide(b: Boundary, x: np.ndarray, v: np.ndarray):
    """collide() and obstacle_sdf() on each row: (x, v) after, and phi, n before."""
    x, v = np.asarray(x, np.float32), np.asarray(v, np.float32)
    phi, n = np.zeros(len(x), np.float32), np.zeros_like(x)

    @ti.kernel
    def run(
        b: ti.template(), xs: ti.types.ndarray(), vs: ti.types.ndarray(), ph: ti.types.ndarray(), ns: ti.types.ndarray()
    ):
        for i in range(xs.shape[0]):
            p = ti.Vector([xs[i, k] for k in ti.static(range(b.dim))])
            u = ti.Vector([vs[i, k] for k in ti.static(range(b.dim))])
            d, nrm = b.obstacle_sdf(p)
            ph[i] = d
            p, u = b.collide(p, u)
            for k in ti.static(range(b.dim)):
                xs[i, k], vs[i, k], ns[i, k] = p[k], u[k], nrm[k]

    run(b, x, v, phi, n)
    return x, v, phi, n


def _post(dim):
    """demo_2d's post, 3.2 cm thick from the floor to 0.5 m (in 3D 4 cm across)."""
    return _boundary(dim, [1.12, 0.0, 0.18][:dim], [1.152, 0.5, 0.22][:dim])


def test_a_particle_in_a_post_near_the_floor_leaves_by_the_nearer_side(dim, taichi_f32):
    b = _post(dim)
    # 1 mm above the floor, 4 mm (left half) and 3 mm (right half) into the post: the floor is
    # the nearest face of the box, but it is shut, so the particle leaves by its side
    x = np.array([[1.124, 0.001, 0.2][:dim], [1.149, 0.001, 0.2][:dim]])
    v = np.array([[3.0, -1.0, 0.0][:dim], [-3.0, -1.0, 0.0][:dim]])
    x1, v1, phi, _ = _collide(b, x, v)
    np.testing.assert_allclose(x1[:, 0], [1.12, 1.152], atol=1e-6)
    np.testing.assert_allclose(x1[:, 1], 0.001, atol=1e-6)
    np.testing.assert_allclose(phi, [-0.004, -0.003], atol=1e-6)
    assert v1[0, 0] <= 0.0 <= v1[1, 0], v1  # the velocity into the side is gone


def test_a_step_through_the_floor_under_a_post_ends_beside_it(dim, taichi_f32):
    """A particle beside the post's foot whose step ends below the floor, under the post:
    the floor puts it back on the floor, inside the post, which pushes it out by its
    nearer side (the other way round, the post did not see it below the floor and the
    floor left it in the footprint)."""
    b = _post(dim)
    x = np.array([[1.123, -0.002, 0.2][:dim], [1.150, -0.001, 0.2][:dim]])
    v = np.array([[2.0, -1.5, 0.0][:dim], [-2.0, -1.0, 0.0][:dim]])
    x1, v1, _, _ = _collide(b, x, v)
    np.testing.assert_allclose(x1[:, 0], [1.12, 1.152], atol=1e-6)
    np.testing.assert_allclose(x1[:, 1], 0.0, atol=1e-7)
    np.testing.assert_allclose(v1, 0.0, atol=1e-7)  # into the floor and into the post: gone


def test_a_floating_box_keeps_its_bottom_face_open(dim, taichi_f32):
    """Only a face on a wall is shut: a box off the floor still projects down through its
    bottom when that face is the nearest."""
    b = _boundary(dim, [1.12, 0.1, 0.18][:dim], [1.152, 0.5, 0.22][:dim])
    x1, _, phi, n = _collide(b, np.array([[1.136, 0.101, 0.2][:dim]]), np.zeros((1, dim)))
    np.testing.assert_allclose(x1[0, 1], 0.1, atol=1e-6)
    np.testing.assert_allclose(phi, [-0.001], atol=1e-6)
    assert n[0, 1] == -1.0


def test_a_wall_to_wall_divider_projects_sideways(dim, taichi_f32):
    """A box from the floor to the lid has both faces of that axis shut: a particle near
    either leaves by a side."""
    b = _boundary(dim, [1.12, 0.0, 0.0][:dim], [1.152, 0.8, 0.4][:dim])
    x = np.array([[1.125, 0.001, 0.2][:dim], [1.148, 0.799, 0.2][:dim]])
    x1, _, _, _ = _collide(b, x, np.zeros((2, dim)))
    np.testing.assert_allclose(x1[:, 0], [1.12, 1.152], atol=1e-6)


def test_outside_the_box_the_distance_is_unchanged(dim, taichi_f32):
    """Shutting a face changes only the projection from inside: outside, the distance and
    its normal are the box's own (numpy's twin in tools/soak.py checks the same)."""
    b = _post(dim)
    rng = np.random.default_rng(7)
    lo, hi = np.array([1.0, 0.0, 0.1][:dim]), np.array([1.3, 0.7, 0.3][:dim])
    x = rng.uniform(lo, hi, (400, dim))
    c, half = np.array([1.136, 0.25, 0.2][:dim]), np.array([0.016, 0.25, 0.02][:dim])
    q = np.abs(x - c) - half
    out = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    keep = out > 1e-4
    _, _, phi, n = _collide(b, x[keep], np.zeros((int(keep.sum()), dim)))
    np.testing.assert_allclose(phi, out[keep], atol=2e-6)
    normal = np.maximum(q[keep], 0.0) * np.sign(x[keep] - c) / out[keep][:, None]
    np.testing.assert_allclose(n, normal, atol=1e-4)


@pytest.mark.parametrize(
    ("lo", "hi", "shut_lo", "shut_hi"),
    [
        ([1.12, 0.0], [1.152, 0.5], [0, 1], [0, 0]),  # a post on the floor
        ([1.12, -0.1], [1.152, 0.9], [0, 1], [0, 1]),  # past the floor and the lid
        ([0.0, 0.0], [1.6, 0.8], [0, 0], [0, 0]),  # the whole domain: no face to leave by
        ([0.5, 0.2], [0.6, 0.3], [0, 0], [0, 0]),  # floating
    ],
)
def test_shut_faces(lo, hi, shut_lo, shut_hi):
    a, b = shut_faces(np.array(lo), np.array(hi), np.array([0.0, 0.0]), np.array([1.6, 0.8]))
    assert a.tolist() == shut_lo and b.tolist() == shut_hi


def test_the_corner_of_a_box_on_the_floor_reads_as_the_open_floor(dim):
    """A lattice at rest around a box standing on the floor: the particle in the corner
    between the box's face and the floor sums its density as one on the open floor does.
    The quadrant below the floor and behind the face is the floor's image of the box's
    image (``Boundary.corner_image``); without it the corner read 3.8 % (2D) and 2.9 % (3D)
    light, so a dam break hitting the box met too little pressure in the corner."""
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    s = 0.01
    lo, hi = [0.2, 0.0, 0.05][:dim], [0.3, 0.08, 0.15][:dim]
    # the water around the box, in blocks that leave it out: beside it, above it, and in 3D before and behind it
    blocks = [
        ([0.0, 0.0, 0.0], [0.2, 0.15, 0.2]),
        ([0.3, 0.0, 0.0], [0.4, 0.15, 0.2]),
        ([0.2, 0.08, 0.0], [0.3, 0.15, 0.2]),
    ]
    if dim == 3:
        blocks += [([0.2, 0.0, 0.0], [0.3, 0.08, 0.05]), ([0.2, 0.0, 0.15], [0.3, 0.08, 0.2])]
    scene = {
        "description": "water at rest around a box on the floor",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [0.4, 0.3, 0.2][:dim]},
        "particles": {"spacing": s},
        "fluid": {"blocks": [{"min": a[:dim], "max": b[:dim]} for a, b in blocks]},
        "obstacles": [{"shape": "box", "min": lo, "max": hi}],
    }
    sim = Simulation(load_scene(scene), arch="cpu")
    sim.run_phases("density")
    seen = sim.particles(virtual=False)
    x, rho = seen["x"], seen["rho"]

    def at(*q):
        k = int(np.argmin(np.linalg.norm(x - np.array(q[:dim]), axis=1)))
        return float(rho[k])

    corner = at(0.195, 0.005, 0.1)  # half a spacing from the face and from the floor
    floor = at(0.105, 0.005, 0.1)
    assert abs(corner / floor - 1.0) < 1e-4, f"{dim}D corner {corner:.2f} against the floor's {floor:.2f} kg/m^3"
