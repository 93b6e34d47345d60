"""Newmark-beta (Newmark 1959) with the grid reset every step (u_n = 0 on the grid, method.md).

The step's unknown is the displacement increment ``du``; the end-of-step acceleration and
velocity follow from it and the start-of-step grid fields ``v_n``, ``a_n``::

    a_{n+1} = (du - dt v_n - dt^2 (1/2 - beta) a_n) / (beta dt^2)
    v_{n+1} = v_n + dt ((1 - gamma) a_n + gamma a_{n+1})

The same functions serve the UFL forms (``forms/incompressible.py``) and the step's grid
arrays, so the two can never disagree.
"""

__all__ = ["acceleration", "end_velocity", "velocity"]


def acceleration(du, v_n, a_n, dt, beta):
    """``a_{n+1} = (du - dt v_n - dt^2 (1/2 - beta) a_n) / (beta dt^2)``."""
    return (du - dt * v_n - dt**2 * (0.5 - beta) * a_n) / (beta * dt**2)


def velocity(du, v_n, a_n, dt, beta, gamma, a_new=None):
    """``v_{n+1} = v_n + dt ((1 - gamma) a_n + gamma a_{n+1})``; ``a_new`` if already computed."""
    if a_new is None:
        a_new = acceleration(du, v_n, a_n, dt, beta)
    return end_velocity(v_n, a_n, a_new, dt, gamma)


def end_velocity(v_n, a_n, a_new, dt, gamma):
    """``v_{n+1} = v_n + dt ((1 - gamma) a_n + gamma a_{n+1})`` from both accelerations."""
    return v_n + dt * ((1 - gamma) * a_n + gamma * a_new)
