"""spin_until: returns as soon as the condition holds, without spinning when it already does, and
False once the timeout has passed."""
from vla_common.ros.spin import spin_until


def test_spins_until_the_condition_holds():
    spins = []
    assert spin_until(spins.append, lambda: len(spins) >= 3, 10.0, slice_s=0.0)
    assert spins == [0.0, 0.0, 0.0]


def test_a_condition_that_holds_needs_no_spin_and_one_that_never_does_times_out():
    spins = []
    assert spin_until(spins.append, lambda: True, 0.0) and spins == []
    assert not spin_until(spins.append, lambda: False, 0.0)
