"""The level coupling (METHOD.md §3–4, thesis §3.3): what virtual particles carry and how
their forces reach the real particles they stand for. One object per
``adaptivity.coupling`` mode; the density, force and integration passes call its hooks
(``ti.func``s), and the step's list (``sph/step.py``) takes its passes at fixed points,
each built here from the part it needs, passed in:

- ``before_density(density)``: the fine particles' neighbour lists, then the
  virtual-mass limiter (``limiter.py``), when it is on;
- ``after_density(forces)``: the virtual state (variational: virtual particles take
  their owners' density, pressure and velocity; ``VirtualState``);
- ``after_forces(forces, viscosity)``: the reactions and virtual velocities (symmetric
  coupling; ``SymmetricReactions``);
- device hooks: ``sum_mass``/``sum_scale`` (how a sum weighs a particle), ``density_skip``,
  ``partner_pressure``, ``skip2``/``interacts`` (which pairs meet), ``hand_reaction``
  (force pass), ``take_reaction`` (integrator), ``advect`` (the virtual particles follow
  their owners, Eq. 24).

``Uniform`` is the run without adaptivity (no virtual particles), ``Variational`` the
default, ``Symmetric`` METHOD.md §4's form.
"""

import taichi as ti

from mrsph.sph.kernels import poly6
from mrsph.sph.particles import DEAD, ROLE_PARENT, VIRTUAL_CHILD, VIRTUAL_PARENT, is_real, is_virtual
from mrsph.sph.step import Pass

from .limiter import VirtualMassLimiter


@ti.data_oriented
class Uniform:
    """No adaptivity: one level, every particle of the nominal mass m0."""

    mode = "none"
    variational = symmetric = limit_virtual = False
    reaction = None
    # accepted and kept in the scene (the window carries it across a refinement toggle);
    # without virtual particles there is no spring to tune
    live_keys = ("adaptivity.spring_rate",)

    def __init__(self, core):
        self.dim = core.dim
        self.pool, self.lev, self.nb = core.pool, core.lev, core.nb

    # ------------------------------------------------------------------ host hooks
    def reset(self) -> None:
        pass

    def set_param(self, key: str, value) -> None:
        pass

    def before_density(self, density) -> list:
        return []

    def after_density(self, forces) -> list:
        return []

    def after_forces(self, forces, viscosity) -> list:
        return []

    # ------------------------------------------------------------------ device hooks
    @ti.func
    def sum_mass(self, j):
        """m_j as a density or force sum weighs particle j. Without adaptivity every
        particle has the nominal mass m0 (one level, no split or merge): the sums count 1
        and are scaled by m0 (m0² for the pair forces) once (``sum_scale``), one load
        fewer per candidate or pair."""
        return 1.0

    @ti.func
    def sum_scale(self):
        return self.lev.m[0]

    @ti.func
    def density_skip(self, i):
        """Particles the density pass leaves alone."""
        return self.pool.p[i].kind == DEAD

    @ti.func
    def partner_pressure(self, kind_j, p_j):
        """The pressure of particle j as it enters the pair force on a real particle."""
        return p_j

    @ti.func
    def skip2(self, i, l):
        return -1.0

    @ti.func
    def interacts(self, j, r2, skip2):
        """Does real particle i take a force from same-level particle j at squared
        distance r2 (given i's ``skip2``)? Always, without virtual particles (no load of
        j's kind and no test per pair)."""
        return True

    @ti.func
    def hand_reaction(self, j, f):
        pass

    @ti.func
    def take_reaction(self, i, f):
        return f

    @ti.func
    def advect(self, j, dt):
        pass

    @ti.func
    def follow_owners(self, j, vel: ti.template()):
        pass

    @ti.func
    def place(self, j):
        pass


@ti.data_oriented
class Adaptive(Uniform):
    """What both adaptive modes share: real masses in the sums, the limiter, the springs
    that tie virtual particles to their owners."""

    def __init__(self, core, adaptivity, fade, offsets):
        """adaptivity: the scene's params; fade: densities as the pressure reads them
        (the limiter's); offsets: the virtual children's sampling offsets (topology)."""
        super().__init__(core)
        self.offsets = offsets
        self.spring_rate = ti.field(float, shape=())
        self.spring_rate[None] = adaptivity.spring_rate
        self.limit_virtual = adaptivity.limit_virtual_density
        self.limiter = VirtualMassLimiter(core, adaptivity, fade) if self.limit_virtual else None

    def set_param(self, key: str, value) -> None:
        self.spring_rate[None] = float(value)

    def before_density(self, density) -> list:
        # the limiter reads the neighbour lists of the fine particles, listed ahead of
        # the density pass (timed as density), and sets the virtual masses (coupling work)
        if self.limiter is None:
            return []
        return [
            Pass("list_fine", "density", density.list_fine, density.list_fine_func, loops=1),
            Pass("limit_virtual", "virtual_coupling", self.limiter.limit, self.limiter.limit_func, loops=1),
        ]

    @ti.func
    def sum_mass(self, j):
        return self.pool.p[j].m

    @ti.func
    def sum_scale(self):
        return 1.0

    @ti.func
    def skip2(self, i, l):
        """The squared distance within which real particle i skips virtual parents: its
        level's ``reach2`` for a transient parent, since that pair already meets at the
        finer level through its virtual children; -1 (none) for any other particle. Taken
        once per particle, not per pair."""
        return ti.select((self.pool.p[i].kind & ROLE_PARENT) != 0, self.lev.reach2[l], -1.0)

    @ti.func
    def interacts(self, j, r2, skip2):
        return r2 >= skip2 or self.pool.p[j].kind != VIRTUAL_PARENT

    @ti.func
    def hand_on(self, j, r, into: ti.template()):
        """Add the reaction r on virtual particle j to ``into`` of the real particle(s) j
        stands for (METHOD.md §4, thesis Fig. 7): a virtual child's transient parent, or
        a virtual parent's children in shares of their masses. A virtual parent moves
        with its children's mass-weighted mean (``follow_owners``), so the mass shares are
        that map's transpose: the reaction does the same work on the children as on j,
        and an implicit solve's operator stays symmetric. A split leaves the children's
        masses equal (even shares); an absorption or a gather can leave them unequal."""
        p = ti.static(self.pool.p)
        if p[j].kind == VIRTUAL_CHILD:
            ti.atomic_add(into[p[j].parent], r)
        else:
            n = p[j].nchild
            m, first, equal = 0.0, 0.0, True
            for q in range(n):
                mc = p[self.pool.children[j, q]].m
                if q == 0:
                    first = mc
                m += mc
                equal = equal and mc == first
            for q in range(n):
                ch = self.pool.children[j, q]
                # equal masses, as a split leaves them, take r / n: the same shares without
                # the rounding of their summed mass
                share = r / n
                if not equal:
                    share = r * (p[ch].m / m)
                ti.atomic_add(into[ch], share)

    @ti.func
    def follow_owners(self, j, vel: ti.template()):
        """Virtual particle j takes its owners' velocity, in the field ``vel`` (the
        particles' own, or a field of velocity changes): a virtual child its transient
        parent's, a virtual parent its children's mass-weighted mean (an implicit pressure
        solve's iterations change the owners' velocities)."""
        p = ti.static(self.pool.p)
        if p[j].kind == VIRTUAL_CHILD:
            vel[j] = vel[p[j].parent]
        else:
            m = 0.0
            mv = ti.Vector.zero(float, self.dim)
            for q in range(p[j].nchild):
                ch = self.pool.children[j, q]
                m += p[ch].m
                mv += p[ch].m * vel[ch]
            if m > 0.0:
                vel[j] = mv / m

    @ti.func
    def anchor(self, j):
        """Where virtual particle j's spring pulls it: a virtual child to its transient
        parent at its sampling offset (half the level spacing per axis), a virtual parent
        to its children's barycentre."""
        p = ti.static(self.pool.p)
        anchor = p[j].x
        if p[j].kind == VIRTUAL_CHILD:
            par = p[j].parent
            anchor = p[par].x + self.offsets[p[j].slot] * self.lev.s[p[j].level]
        else:
            mass = 0.0
            acc = ti.Vector.zero(float, self.dim)
            for q in range(p[j].nchild):
                ch = self.pool.children[j, q]
                acc += p[ch].m * p[ch].x
                mass += p[ch].m
            if mass > 0.0:
                anchor = acc / mass
        return anchor

    @ti.func
    def place(self, j):
        """Virtual particle j on its anchor, at its owners' velocity: after a solver moved
        the owners (``pbf``), as a spring at k dt >= 1 puts it (``advect``)."""
        self.pool.p[j].x = self.anchor(j)
        self.follow_owners(j, self.pool.p.v)

    @ti.func
    def advect(self, j, dt):
        """Virtual particle j follows its level's flow, tied by a Hooke spring (Eq. 24):
        a virtual child to its transient parent at its sampling offset (rest length half
        the level spacing per axis), a virtual parent to its children's barycentre (rest
        length zero). The springs act on virtual particles only."""
        p = ti.static(self.pool.p)
        relax = ti.min(self.spring_rate[None] * dt, 1.0)
        anchor = self.anchor(j)
        # advected, then pulled towards the anchor by the spring, integrated implicitly
        # (a relaxation by k dt, capped at 1) so that any stiffness is stable; at
        # k dt >= 1 the virtual particle sits on its anchor, an exact function of its
        # owners' positions, as the energy balance of the variational coupling needs
        x = p[j].x + dt * p[j].v
        x += relax * (anchor - x)
        # not projected out of walls: a virtual particle stands for part of its owner's
        # mass at a fixed offset; projecting it would stack the children of neighbouring
        # parents onto the same wall points (measured: virtual density 1.8 rho0 on the
        # floor of demo_2d within 0.05 s). The grid is padded by two cells, so a
        # position slightly inside a wall is still binned.
        p[j].x = x


@ti.data_oriented
class Variational(Adaptive):
    """The default coupling: a virtual particle is a piece of real matter seen from
    another level, and the pressure forces derive from one energy.

    ``partner_pressure`` is 0 for a virtual j: the pressure forces then derive from Σ over
    real particles of m u(ρ), in which each real particle's density sums its own level,
    virtual particles included, and each virtual position is a function of its owners'
    (``advect``). A real particle's pressure pushes its same-level neighbours, real or
    virtual, and the virtual ones hand the reaction to their owners. A fine–coarse pair
    thus meets twice, once with each particle's own pressure, and its pressure acts once.
    Its viscous and artificial-viscosity terms are whole pair terms in both meetings, so
    the shear across a level interface is coupled twice over: halving them for virtual
    partners let the fine fluid run further ahead (docs/METHOD.md §13), so the interface
    keeps the extra damping. In a resting pool with a refined box it moves less than the
    symmetric form, whose virtual pressures come from virtual densities that reach 1.3 ρ0
    where virtual children overlap each other and the walls (docs/METHOD.md §13)."""

    mode = "variational"
    variational = True

    def __init__(self, core, adaptivity, fade, offsets):
        super().__init__(core, adaptivity, fade, offsets)
        # reactions of the forces from virtual particles, handed on to their owners during
        # the force pass; zero between steps (``take_reaction``)
        self.reaction = ti.Vector.field(self.dim, float, shape=core.pool.capacity)

    def reset(self) -> None:
        self.reaction.fill(0.0)

    def after_density(self, forces) -> list:
        state = VirtualState(self.pool, forces)
        return [Pass("virtual_state", "virtual_coupling", state.run, state.run_func)]

    @ti.func
    def density_skip(self, i):
        # a virtual particle's state comes from its owners (``virtual_state``), and its
        # reactions are handed on by the force pass: no sum, no list
        k = self.pool.p[i].kind
        return k == DEAD or is_virtual(k)

    @ti.func
    def partner_pressure(self, kind_j, p_j):
        result = p_j
        if is_virtual(kind_j):
            result = 0.0
        return result

    @ti.func
    def hand_reaction(self, j, f):
        if is_virtual(self.pool.p[j].kind):
            self.hand_on(j, -f, self.reaction)

    @ti.func
    def take_reaction(self, i, f):
        """F_i with the reactions handed on to i, zeroed here for the next force pass
        (which hands them only to real particles)."""
        out = f + self.reaction[i]
        self.reaction[i] = ti.Vector.zero(float, self.dim)
        return out


@ti.data_oriented
class Symmetric(Adaptive):
    """METHOD.md §4's form: virtual particles have a density and pressure of their own
    neighbourhood, and each pair of real particles on either side of a level interface
    interacts exactly once. A fine particle i and a coarse particle P could meet twice: at
    the fine level through P's virtual children (reaction to P) and at the coarse level
    through i's virtual parent (reaction to i); counting both pushes the two sides apart
    with an extra pressure·area at every interface. So the pair interacts at the finer
    level whenever P carries virtual children, and through the virtual parent only when P
    has none (``skip2``, ``Levels.reach2``). Virtual parents always give the coarse side
    its density."""

    mode = "symmetric"
    symmetric = True

    def after_forces(self, forces, viscosity) -> list:
        reactions = SymmetricReactions(self, forces, viscosity)
        return [Pass("virtual_reactions", "virtual_coupling", reactions.run, reactions.run_func, loops=1)]


@ti.data_oriented
class VirtualState:
    """The variational coupling's pass after the density: a virtual particle takes its
    owners' state, and the pair factors the force pass reads of it (``forces.factors``)."""

    def __init__(self, pool, forces):
        self.pool, self.forces, self.dim = pool, forces, pool.dim

    @ti.kernel
    def run(self, n: ti.i32):
        self.run_func(n)

    @ti.func
    def run_func(self, n):
        """A virtual particle takes its owners' density, pressure and velocity (a virtual
        child 1/2^d of its transient parent, a virtual parent the sum of its transient
        children, mass-weighted), not those of its own neighbourhood, where virtual
        children of neighbouring parents overlap each other and the walls."""
        p = ti.static(self.pool.p)
        for j in range(n):
            kj = p[j].kind
            if kj == VIRTUAL_CHILD:
                par = p[j].parent
                p[j].rho = p[par].rho
                p[j].p = p[par].p
                p[j].v = p[par].v
                self.forces.factors(j)
            elif kj == VIRTUAL_PARENT:
                m, r, pr = 0.0, 0.0, 0.0
                mv = ti.Vector.zero(float, self.dim)
                for q in range(p[j].nchild):
                    ch = self.pool.children[j, q]
                    m += p[ch].m
                    r += p[ch].m * p[ch].rho
                    pr += p[ch].m * p[ch].p
                    mv += p[ch].m * p[ch].v
                if m > 0.0:
                    p[j].rho = r / m
                    p[j].p = pr / m
                    p[j].v = mv / m
                    self.forces.factors(j)


@ti.data_oriented
class SymmetricReactions:
    """The symmetric coupling's pass after the forces: the reactions of the real-virtual
    forces handed to the real particles the virtual ones stand for, and the virtual
    particles' velocities interpolated from their level."""

    def __init__(self, coupling, forces, viscosity):
        self.coupling, self.forces, self.viscosity = coupling, forces, viscosity
        self.dim, self.pool, self.lev, self.nb = coupling.dim, coupling.pool, coupling.lev, coupling.nb

    @ti.func
    def _coupling_visit(self, j, i, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """Virtual particle j and candidate i: the reaction on j of the force on a real i,
        and i's interpolation weight for j's velocity. ctx: h, cs, cv, μ, reach², poly6
        constant; acc: (reaction, Σ w u, Σ w)."""
        p = ti.static(self.pool.p)
        h = ctx[0]
        h2 = h * h
        r = p[i].x - xq
        r2 = r.norm_sqr()
        if r2 < h2 and is_real(p[i].kind):
            reaction = ti.Vector.zero(float, self.dim)
            if r2 > 0.0 and self.coupling.interacts(j, r2, ti.select((p[i].kind & ROLE_PARENT) != 0, ctx[4], -1.0)):
                reaction = -self.forces.pair(i, j, r, ti.sqrt(r2), h, ctx[1], ctx[2], ctx[3])
            w = p[i].m / p[i].rho * poly6(r2, h2, ctx[5])
            for k in ti.static(range(self.dim)):
                acc[k] += reaction[k]
                acc[self.dim + k] += w * p[i].v[k]
            acc[2 * self.dim] += w

    @ti.kernel
    def run(self, n: ti.i32):
        self.run_func(n)

    @ti.func
    def run_func(self, n):
        """Hand the reaction of each real–virtual force to the real particles the virtual
        one stands for (``hand_on``: METHOD.md §4, thesis Fig. 7), and interpolate the
        virtual particle's velocity from the real particles of its level."""
        p = ti.static(self.pool.p)
        mu = self.viscosity.mu[None]
        for j in range(n):
            kj = p[j].kind
            if is_virtual(kj):
                l = p[j].level
                xj = p[j].x
                ctx = ti.Vector(
                    [self.lev.h[l], self.lev.spiky[l], self.lev.visc[l], mu, self.lev.reach2[l], self.lev.poly6[l]]
                )
                acc = ti.Vector.zero(float, 2 * self.dim + 1)
                eye = ti.Matrix.identity(float, self.dim)
                self.nb.candidates(
                    j, xj, eye, xj, xj, False, l, self.nb.is_listed(j), False, self._coupling_visit, ctx, acc
                )
                reaction = ti.Vector([acc[k] for k in ti.static(range(self.dim))])
                vsum = ti.Vector([acc[self.dim + k] for k in ti.static(range(self.dim))])
                wsum = acc[2 * self.dim]
                self.coupling.hand_on(j, reaction, p.a)
                # the velocity interpolated from the real particles of the level
                if wsum > 0.0:
                    p[j].v = vsum / wsum
                elif kj == VIRTUAL_CHILD:
                    p[j].v = p[p[j].parent].v
                else:
                    vm = ti.Vector.zero(float, self.dim)
                    for q in range(p[j].nchild):
                        vm += p[self.pool.children[j, q]].v
                    p[j].v = vm / ti.max(p[j].nchild, 1)


MODES = {"variational": Variational, "symmetric": Symmetric}


def make(core, adaptivity, fade, offsets=None):
    """The coupling of the scene's ``adaptivity`` params: ``Uniform`` without adaptivity."""
    if not core.adaptive:
        return Uniform(core)
    return MODES[adaptivity.coupling](core, adaptivity, fade, offsets)
