"""A trajectory whose state stops being finite is an error, not an early end (docs/reliability.md): in the kernel a
NaN position finds no wall ahead, which would end the trajectory like an escape, marked complete. The run stops
before the block holding the NaN is written; a run file keeps every record up to its last checkpoint, marked
incomplete. Config validation refuses the inputs known to produce NaN (tests/test_errors.py); this is the net
behind it, exercised by putting a NaN into a real simulation's state."""
import h5py
import numpy as np
import pytest

from rbx import api, config
from rbx.simulation import MemorySink, NonFiniteState, Simulation

CFG = {"table": {"kind": "stadium", "radius": 0.5, "length": 1.0},
       "boundary": {"default": {"rule": "constant", "rank": 1}}, "ball": {"radius": 0.1},
       "initial": {"sample": "billiard"}, "run": {"collisions": 50, "trajectories": 3, "seed": 2},
       "output": {"record": ["time", "position"]}}


def test_a_nan_state_stops_the_run_with_an_error():
    sim = Simulation(config.from_dict(CFG))
    sim.vel[1] = np.nan
    with pytest.raises(NonFiniteState) as info:
        sim.run(MemorySink())
    assert "trajectory 1" in str(info.value)
    # the same run without the NaN completes: the check does not fire on finite states
    clean = Simulation(config.from_dict(CFG))
    assert clean.run(MemorySink()) is True


def test_a_nan_state_leaves_an_incomplete_readable_file(tmp_path):
    out = tmp_path / "nan.h5"
    sim = Simulation(config.from_dict(CFG))
    sim.pos[2, 0] = np.inf
    with pytest.raises(NonFiniteState):
        api.run_to_file(sim, str(out))
    path = out if out.exists() else tmp_path / "nan.h5.partial"
    with h5py.File(path, "r") as h5:
        assert not h5.attrs["complete"]
        assert np.all(h5["collisions/count"][...] == 0)          # not even record 0 with its infinite position


@pytest.mark.parametrize("ahead", [False, True])
def test_a_nan_reached_mid_run_keeps_the_blocks_before_it(ahead, monkeypatch):
    """A NaN appears in the state during the second block (put there as that block's kernel returns): the run
    stops before writing that block, the first one kept, whether blocks are computed one after the other or the
    next one while this one is written (simulation.AHEAD: the check then reads the copy of the state at the
    block's end)."""
    import rbx.simulation as simulation
    monkeypatch.setattr(simulation, "AHEAD", ahead)
    monkeypatch.setattr(simulation, "BLOCK_WORK", 3000)
    sim = Simulation(config.from_dict({**CFG, "run": {"collisions": 200000, "trajectories": 3, "seed": 2}}))
    calls = {"n": 0}
    original = Simulation.advance

    def advance(self, stop, bufs):
        nrec = original(self, stop, bufs)
        calls["n"] += 1
        if calls["n"] == 2:
            self.W[0] = np.nan
        return nrec
    monkeypatch.setattr(Simulation, "advance", advance)
    sink = MemorySink()
    with pytest.raises(NonFiniteState) as info:
        sim.run(sink)
    assert "trajectory 0" in str(info.value)
    assert len(sink.blocks) == 2 and sink.count.min() > 1          # record 0 and the first block, not the second
    assert np.all(np.isfinite(sink.records["time"][:, :sink.count.min()]))