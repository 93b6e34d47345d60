"""The clock of a scheme: the adaptive step's choice, landing on output times, retries at half the step."""

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm.errors import InputError, SimulationDiverged
from fempm.implicit import ImplicitSolver
from fempm.linear import SolveFailed
from fempm.options import Controls, Physics, Scheme
from fempm.stepper import PRESSURE_COURANT, StepControl, Stepper


class Ballistic(Stepper):
    """A point moving at a constant speed, whose step fails above ``breaks`` (a scheme's failure)."""

    def __init__(self, speed, control, breaks=np.inf):
        super().__init__(control.largest, control)
        self.speed, self.breaks, self.x = speed, breaks, 0.0

    def advance(self, dt):
        self.x += self.speed * dt
        if dt > self.breaks:
            raise SolveFailed(f"dt = {dt:g} is too large")

    def fastest(self):
        return self.speed

    def cell_size(self):
        return 0.1

    def save(self):
        return self.x

    def restore(self, saved):
        self.x = saved


def test_the_step_follows_the_courant_number_the_bound_and_the_growth_limit():
    control = StepControl(courant=0.5, largest=0.2, growth=1.25)
    assert control.choose(fastest=1.0, h=0.1, previous=None) == pytest.approx(0.05)  # C h / |v|
    assert control.choose(fastest=0.0, h=0.1, previous=None) == 0.2  # at rest: the bound
    assert control.choose(fastest=0.1, h=0.1, previous=0.1) == pytest.approx(0.125)  # at most 1.25 x the last
    # the pressure's speed bounds it whatever C: PRESSURE_COURANT h / sqrt(p / rho)
    assert control.choose(fastest=0.0, h=0.1, previous=None, pressure_speed=1.0) == pytest.approx(PRESSURE_COURANT * 0.1)
    assert control.choose(fastest=10.0, h=0.1, previous=None, pressure_speed=1.0) == pytest.approx(0.005)
    with pytest.raises(InputError, match="courant"):
        StepControl(courant=0.0, largest=0.1).check()


def test_steps_land_exactly_on_the_target_without_a_sliver():
    s = Ballistic(speed=1.0, control=StepControl(courant=0.5, largest=1.0))  # dt = 0.05
    while s.time < 0.12:
        s.step(until=0.12)
    assert s.time == 0.12 and s.steps == 3  # 0.12 in three equal steps of 0.04, not 0.05 + 0.05 + 0.02
    assert s.x == pytest.approx(0.12, rel=1e-15)


def test_a_failed_step_is_retried_at_half_its_size_from_its_saved_state():
    s = Ballistic(speed=1.0, control=StepControl(courant=0.5, largest=1.0, retries=3), breaks=0.02)
    s.step()
    assert s.dt == pytest.approx(0.0125) and s.x == pytest.approx(0.0125)  # 0.05 -> 0.025 -> 0.0125
    assert [r[2] for r in s.retries] == pytest.approx([0.05, 0.025]) and "too large" in s.retries[0][3]
    hopeless = Ballistic(speed=1.0, control=StepControl(courant=0.5, largest=1.0, retries=2), breaks=0.001)
    with pytest.raises(SimulationDiverged, match=r"step 1\): dt = 0.0125 is too large \(the step failed at 0.05, "
                                                 r"0.025, 0.0125 s: halving it 2 times did not help\)$"):
        hopeless.step()
    fixed = Ballistic(speed=1.0, control=StepControl(courant=0.5, largest=1.0, retries=0), breaks=0.001)
    with pytest.raises(SimulationDiverged, match=r"is too large$"):  # no retries: the failure as it came
        fixed.step()


def test_still_water_takes_its_step_from_the_pressure_speed():
    """A column at rest (the dam break's, 20 cells deep): its particles hardly move, so its step is
    PRESSURE_COURANT h / max sqrt(p / rho) over the particles (fempm.stepper.StepControl), whatever C, not the
    largest step."""
    grid = fempm.Grid.from_cells(MPI.COMM_SELF, (0.0, 0.0), (0.146, 0.584), (10, 40))
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (0.146, 0.292)), per_cell=2, density=1000.0)
    solver = ImplicitSolver(fempm.BSpline2(grid), water, scheme=Scheme(dt=1e-2, courant=0.4),
                            physics=Physics(viscosity=1e-3, gravity=(0.0, -9.81)))
    solver.step()  # from p = 0: the largest step
    assert solver.dt == 1e-2
    speed = np.sqrt(np.max(water["pressure"] / water["density"]))
    assert speed == pytest.approx(np.sqrt(9.81 * 0.292), rel=0.05)  # measured 1.685 m/s: about sqrt(g D) at the floor
    assert solver.fastest() < 0.01 * speed
    solver.step()
    assert solver.dt == pytest.approx(PRESSURE_COURANT * grid.h / speed, rel=1e-14)  # measured 6.93e-3 s


@pytest.mark.mpi
def test_an_adaptive_dam_break_keeps_its_courant_number_and_lands_on_the_end():
    grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (0.584, 0.584), (40, 40))
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (0.146, 0.292)), per_cell=2, density=1000.0)
    solver = ImplicitSolver(fempm.BSpline2(grid), water, scheme=Scheme(dt=5e-3, courant=0.5),
                            controls=Controls(step_growth=1.25))
    cfl = []
    while solver.time < 0.1:
        fastest = solver.fastest()
        solver.step(until=0.1)
        cfl.append(fastest * solver.dt / grid.h)
    assert solver.time == 0.1
    assert max(cfl) <= 0.5 + 1e-12 and solver.retries == []
    assert solver.steps == 21  # measured (22 with the start configuration's divergence): the step grows from 5e-3 s (at rest) to the Courant limit
