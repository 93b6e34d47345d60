"""Seeding, migration between ranks, and the errors of the particle store."""

import numpy as np
import pytest

import fempm
from fempm.errors import InputError, ParticleOutsideGridError


@pytest.mark.mpi
def test_seeding_counts_and_ids_do_not_depend_on_ranks(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (0.584, 0.584), 0.0146)
    particles = fempm.Particles(grid)
    n = particles.seed(fempm.Rectangle((0.0, 0.0), (0.146, 0.292)), per_cell=2, density=1000.0)
    assert n == 800  # the seed's dam break: 10 x 20 cells, 4 per cell
    ids = np.concatenate(comm.allgather(particles.id))
    assert len(np.unique(ids)) == 800
    assert np.sum(comm.allgather(particles["mass"].sum())) == pytest.approx(1000 * 0.146 * 0.292, rel=1e-12)
    assert np.all(grid.owner[particles.cell] == comm.rank)


def test_polygon_and_union_of_bodies(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    particles = fempm.Particles(grid)
    triangle = fempm.Polygon(((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)))
    n1 = particles.seed(triangle, per_cell=2, density=1.0)
    n2 = particles.seed(fempm.Rectangle((0.0, 0.0), (0.5, 0.5)), per_cell=2, density=1.0)
    # 400 sub-cell centres, those strictly below the diagonal x + y < 1: 190; the square adds none
    assert (n1, n2) == (190, 0)


@pytest.mark.mpi
def test_migration_round_trip_keeps_every_id_once(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.05)
    particles = fempm.Particles(grid)
    total = particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=2, density=1.0)
    ids_before = np.sort(np.concatenate(comm.allgather(particles.id)))
    x_before = dict(zip(particles.id.tolist(), map(tuple, particles.x)))
    # mirror every particle (most change rank), relocate, mirror back, relocate
    for _ in range(2):
        particles.fields["x"] = 1.0 - particles.x
        particles.relocate()
        assert np.all(grid.owner[particles.cell] == comm.rank)
    ids_after = np.sort(np.concatenate(comm.allgather(particles.id)))
    assert particles.global_count() == total
    np.testing.assert_array_equal(ids_before, ids_after)
    for i, x in zip(particles.id.tolist(), particles.x):
        assert i in x_before and np.allclose(x, x_before[i], atol=1e-15)


def test_leaving_the_grid_is_an_error_unless_deletion_is_chosen(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    particles = fempm.Particles(grid)
    particles.add_points(np.array([[0.5, 0.5], [0.25, 0.25]]), 0.01, density=2.0, ids=np.array([10, 11]))
    particles.fields["x"][particles.id == 11] = [1.25, 0.5]
    with pytest.raises(ParticleOutsideGridError, match=r"particle 11 at \(1\.25, 0\.5\)"):
        particles.relocate()
    keep = fempm.Particles(grid, on_exit="delete")
    keep.add_points(np.array([[0.5, 0.5], [0.25, 0.25]]), 0.01, density=2.0, ids=np.array([10, 11]))
    keep.fields["x"][keep.id == 11] = [1.25, 0.5]
    keep.relocate()
    assert keep.global_count() == 1
    assert comm.allreduce(keep.lost_mass) == pytest.approx(0.02)


@pytest.mark.parametrize(
    "field, value, error, message",
    [
        ("x", np.nan, ParticleOutsideGridError, "particle 0 has a non-finite position"),
        ("volume", 0.0, InputError, "particle 0: volume must be positive"),
        ("volume", -1.0, InputError, "particle 0: volume must be positive"),
        ("mass", np.nan, InputError, "particle 0: mass must be positive"),
    ],
)
def test_bad_particle_data_is_named(comm, field, value, error, message):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    particles = fempm.Particles(grid)
    particles.add_points(np.array([[0.5, 0.5]]) if comm.rank == 0 else np.zeros((0, 2)), 0.01, ids=np.array([0] if comm.rank == 0 else [], dtype=np.int64))
    if comm.rank == 0:
        particles.fields[field][0] = value
        with pytest.raises(error, match=message):
            particles.check()


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p.seed(fempm.Rectangle((0.5, 0.5), (1.5, 1.0)), 2, 1000.0), "not inside the grid"),
        (lambda p: p.seed(fempm.Rectangle((0.0, 0.0), (0.5, 0.5)), 0, 1000.0), "positive integer"),
        (lambda p: p.seed(fempm.Rectangle((0.0, 0.0), (0.5, 0.5)), 2, -1.0), "density must be positive"),
        (lambda p: fempm.Rectangle((0.5, 0.5), (0.2, 1.0)), "must exceed lower"),
        (lambda p: fempm.Polygon(((0, 0), (1, 1))), "at least three"),
        (lambda p: fempm.Particles(p.grid, on_exit="ignore"), "on_exit must be"),
    ],
)
def test_bad_seeding_input_is_named(comm, make, message):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    with pytest.raises(InputError, match=message):
        make(fempm.Particles(grid))
