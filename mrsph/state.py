"""A simulation's state in memory, to put back later: what ``Simulation.save_state`` and
``restore_state`` hand over. It lives here, beside the dumps, rather than in the
simulation, since it only reads and writes the parts' fields."""

from .sph.particles import ATTRIBUTES


def save(sim) -> dict:
    """Numpy copies of every particle attribute, the links, the clocks and the emitters'
    progress (``Simulation.save_state``)."""
    p = sim.pool.p
    return {
        "attributes": {a.name: getattr(p, a.name).to_numpy() for a in ATTRIBUTES},
        "children": sim.pool.children.to_numpy(),
        "n": sim.pool.count(),
        "refused": int(sim.pool.refused[None]),
        "clock": (sim.time, sim.frame, sim.steps, sim.dt, sim.integrator.chosen_dt()),
        "emitters": list(sim.emitters.progress),
        "capacity": sim.capacity,
        "dim": sim.dim,
    }


def restore(sim, state: dict) -> None:
    """Put ``state`` (a :func:`save` of a Simulation of the same scene) into ``sim``; what the
    step kept between steps (lists, a solver's carried slots) is dropped, since the pool's
    slots are not those it was built for."""
    if (state["dim"], state["capacity"]) != (sim.dim, sim.capacity):
        raise ValueError(
            f"restore_state: a {state['dim']}D state of capacity {state['capacity']} "
            f"does not fit this {sim.dim}D pool of capacity {sim.capacity}"
        )
    for name, values in state["attributes"].items():
        getattr(sim.pool.p, name).from_numpy(values)
    sim.pool.children.from_numpy(state["children"])
    sim.pool.n[None] = state["n"]
    sim.pool.refused[None] = state["refused"]
    sim.time, sim.frame, sim.steps, sim.dt, chosen_dt = state["clock"]
    sim.report.restored(state["refused"], sim.steps)
    sim.grids.take_rebuilds()
    sim.state.set_dt(sim.dt)
    sim.integrator.set_chosen_dt(chosen_dt)
    sim.emitters.progress = list(state["emitters"])
    sim.grids.invalidate()
    sim.pressure.forget_step()
    sim.coupling.reset()
    sim._stirrers(sim.time)
