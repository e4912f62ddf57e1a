"""Position based fluids (Macklin & Müller 2013): the scene keys of ``[pbf]`` and their
rules, Taichi-free, read by the scene's schema (``mrsph.scene.config``); the solver is
``solver.py``."""

from mrsph.pressure import key

NAME = "pbf"
DOC = (
    "pbf, position based fluids (Macklin & Müller 2013): density constraints projected on the "
    "positions, a time step tied to the frame (keys in [pbf])"
)

# The [pbf] table: its keys, then its doc (a pair the schema turns into a Table).
TABLE = (
    {
        "substeps": key(
            "int",
            10,
            "[1, 1000]",
            doc="time steps a frame (run.fps): dt = 1 / (fps substeps), whatever the flow; the "
            "step is tied to the frame, not to a sound speed or a CFL bound",
        ),
        "dt": key(
            "float",
            0.0,
            ">= 0",
            "s",
            "a fixed time step instead of substeps (0 = from substeps); the frame's last step is cut "
            "to its end",
        ),
        "iterations": key(
            "int",
            2,
            "[1, 20]",
            doc="constraint iterations a step, each a Jacobi projection of every density constraint "
            "(one pass for the multipliers, one for the corrections)",
        ),
        "relaxation": key(
            "float",
            0.0,
            ">= 0",
            doc="epsilon of the multiplier lambda = -C / (|grad C|^2 + epsilon), as a share of a rest "
            "lattice's |grad C|^2 (constraint force mixing): softer constraints, more compression; "
            "0 = none",
        ),
        "over_relaxation": key(
            "float",
            1.0,
            "(0, 2)",
            doc="share of each iteration's correction that is applied (Jacobi's omega): below 1 damps "
            "the checkerboard modes Jacobi leaves, above 1 converges faster where it is stable",
        ),
        "warm_start": key(
            "float",
            0.5,
            "[0, 0.5]",
            doc="share of the last step's pressure (the accumulated multipliers) that acts as a force in "
            "the next prediction, so that the iterations correct less of the water's weight (without it a "
            "column H deep compresses by about g H |grad C|^2 dt^2 / iterations); above 0.5 the few "
            "iterations a step and the carried pressure feed each other and the long waves grow "
            "(docs/METHOD.md, position based fluids); 0 = none",
        ),
        "artificial_pressure": key(
            "float",
            0.0,
            ">= 0",
            doc="k of the tensile correction s_corr = k (W(r) / W(dq))^n added to each pair's "
            "multipliers (Macklin & Müller's artificial pressure, in units of a rest lattice's "
            "multiplier): it keeps particles from clumping at the free surface; 0 = off",
        ),
        "artificial_pressure_radius": key(
            "float",
            0.2,
            "(0, 1)",
            doc="dq of the tensile correction, as a share of the support h",
        ),
        "artificial_pressure_exponent": key(
            "int",
            4,
            "[1, 8]",
            doc="n of the tensile correction",
        ),
        "viscosity": key(
            "choice",
            "xsph",
            choices=("xsph", "scene"),
            doc="xsph = XSPH velocity smoothing (pbf.xsph) and no force-pass viscosity, so that "
            "nothing bounds the time step; scene = fluid.viscosity and fluid.artificial_viscosity as "
            "the other solvers take them (their time-step bounds then apply)",
        ),
        "xsph": key(
            "float",
            0.1,
            "[0, 1]",
            doc="c of XSPH, u_i += c sum_j (m_j / rho_j) (u_j - u_i) W_ij, each step",
        ),
        "max_displacement": key(
            "float",
            1.0,
            "(0, 4]",
            doc="the velocity clamp: a particle moves at most this share of its level's spacing a "
            "step (|u| <= max_displacement s / dt); the particles it clamps are counted in "
            "stats (clamped) and shown in the window's HUD",
        ),
        "tolerance": key(
            "float",
            0.01,
            "> 0",
            doc="the average density error (rho - rho0)/rho0 over the real particles that a step's "
            "iterations must reach; a step that ends above it is counted in stats (unconverged) and "
            "warned about once, naming what to raise",
        ),
    },
    'The position-based solver (fluid.solver = "pbf"); ignored by the other solvers.',
)


def rules(check, data: dict) -> None:
    """The cross-field rules of a scene that runs this solver (``check.add`` reports)."""
    ad = data["adaptivity"]
    if ad and ad["enabled"] and ad["coupling"] == "symmetric":
        check.add(
            "adaptivity.coupling",
            'not with fluid.solver = "pbf"',
            '"symmetric"',
            '"variational" (the position corrections of a virtual particle go back to its owners, '
            "which it follows)",
        )


def solver_class():
    """The Taichi class (imported here, on first use, so that the keys stay Taichi-free)."""
    from .solver import PBF

    return PBF
