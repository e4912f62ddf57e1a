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
            20,
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
            "[1, 50]",
            doc="constraint iterations a step at most, each a Jacobi projection of every density "
            "constraint (a pass for the multipliers, one for the corrections); a step stops earlier "
            "once its average density error is within pbf.tolerance and its largest within "
            "pbf.max_density_error",
        ),
        "min_iterations": key(
            "int",
            -1,
            ">= -1",
            doc="corrections a step at least, whatever its error, and then more while the error "
            "measured for the last one is above pbf.tolerance or pbf.max_density_error; -1 = "
            "pbf.iterations, a fixed count (a solve that stops as soon as it is within its tolerance "
            "leaves the carried pressure to decay and the next steps swing)",
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
            0.7,
            "(0, 1]",
            doc="share of each iteration's correction that is applied (Jacobi's omega): the particle-"
            "scale checkerboard mode is the one a Jacobi step over-corrects (in 3D, with ~33 neighbours, "
            "past twice its error at omega = 1, so it grows: a resting 3D tank moved at 7 % of sqrt(gH) "
            "at 1.0, 0.7 % at 0.8); 1 = the whole correction",
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
            0.001,
            ">= 0",
            doc="k of the tensile correction s_corr = k (W(r) / W(dq))^n added to each pair's "
            "multipliers (Macklin & Müller's artificial pressure, in units of the coarsest level's rest "
            "lattice multiplier, so that it is one pressure on every level): it keeps the particles from clumping and from losing the lattice's order, whose "
            "loss biases the pressure gradient (a resting tank's pressure read 23 % high without it, 8 % with "
            "0.001); 0 = off",
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
            doc="xsph = XSPH velocity smoothing (pbf.xsph) alone, so that nothing bounds the time "
            "step; scene = fluid.viscosity's Eq. 19 too, within the projection, its viscous bound then "
            "capping the step (no artificial viscosity either way: pbf has no force pass)",
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
            doc="the average density error (rho - rho0)/rho0 over the real particles at which a step's "
            "iterations stop; a step that ends above it (at pbf.iterations) is counted in stats "
            "(unconverged) and warned about once, naming what to raise",
        ),
        "max_density_error": key(
            "float",
            0.0,
            ">= 0",
            doc="and until no particle's density error is above this (0.2 = 20 %), past "
            "pbf.min_iterations: a hot spot of a few dozen particles hides in the average (a corner "
            "the mouse crams water into, 2-4 rho0 there while the average read 1 %, threw a particle "
            "at 437 m/s in the stirred soak); 0 = the average alone",
        ),
    },
    'The position-based solver (fluid.solver = "pbf"); ignored by the other solvers.',
)


def rules(check, data: dict) -> None:
    """The cross-field rules of a scene that runs this solver (``check.add`` reports)."""
    cfg = data["pbf"]
    if cfg and None not in (cfg["iterations"], cfg["over_relaxation"], cfg["min_iterations"]):
        # an odd count of Jacobi iterations at omega near 1 flips the checkerboard mode's
        # error each iteration and grows it (docs/METHOD.md, position based fluids)
        if cfg["iterations"] % 2 and cfg["over_relaxation"] > 0.7:
            check.add(
                "pbf.over_relaxation",
                f"too high for an odd pbf.iterations = {cfg['iterations']}",
                repr(cfg["over_relaxation"]),
                "at most 0.7, or an even pbf.iterations",
            )
        varies = -1 < cfg["min_iterations"] < cfg["iterations"]
        if varies and cfg["over_relaxation"] > 0.7:
            # a count that a step's error sets is odd in some steps
            check.add(
                "pbf.over_relaxation",
                f"too high for a count that varies (pbf.min_iterations = {cfg['min_iterations']} "
                f"below pbf.iterations = {cfg['iterations']})",
                repr(cfg["over_relaxation"]),
                "at most 0.7, or pbf.min_iterations = -1",
            )
        if cfg["min_iterations"] == 0:
            check.add(
                "pbf.min_iterations",
                "0: a step makes at least one correction (the error it stops on is measured for one)",
                "0",
                "-1 or at least 1",
            )
        if cfg["min_iterations"] > cfg["iterations"]:
            check.add(
                "pbf.min_iterations",
                "above pbf.iterations",
                repr(cfg["min_iterations"]),
                f"at most pbf.iterations = {cfg['iterations']}, or -1",
            )
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
