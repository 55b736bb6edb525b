"""Counter-based random streams: draw k of trajectory j is a pure function of (seed, j, purpose, k).

A counter-based generator (SplitMix64 finaliser applied to key + k·golden) needs no shared state, so trajectories
run in any order on any number of threads and give the same numbers, and a run can be resumed by remembering
only how many draws each trajectory made.
"""
import numpy as np

from ._jit import jit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)

#: purpose tags, so that the draws that pick rules and the draws that sample initial states never overlap
PURPOSE_RULES = 1
PURPOSE_INITIAL = 2


@jit
def _mix(z):
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@jit
def stream_key(seed, trajectory, purpose):
    """Key of the stream of one trajectory for one purpose -> uint64."""
    k = _mix(np.uint64(seed) + _GOLDEN)
    k = _mix(k ^ (np.uint64(trajectory) * _M1 + _GOLDEN))
    return _mix(k ^ (np.uint64(purpose) * _M2 + _GOLDEN))


@jit
def draw_bits(key, counter):
    """The 64 random bits of draw number ``counter`` of the stream ``key`` (:func:`uniform` keeps the top 53)."""
    return _mix(np.uint64(key) + (np.uint64(counter) + np.uint64(1)) * _GOLDEN)


@jit
def draw53(key, counter):
    """The top 53 of :func:`draw_bits`: an integer m in [0, 2⁵³), the draw m·2⁻⁵³ of :func:`uniform` (the rule
    trees compare m with integer thresholds, :func:`rbx.rules.thresholds`)."""
    return draw_bits(key, counter) >> np.uint64(11)


@jit
def uniform(key, counter):
    """Draw number ``counter`` of the stream ``key`` -> float in [0, 1) with 53 random bits."""
    return np.float64(draw53(key, counter)) * (1.0 / 9007199254740992.0)


def uniforms(seed, trajectory, purpose, start, count):
    """The draws ``start … start+count-1`` of a stream, as a numpy array (for tests and the reference loop)."""
    key = stream_key(seed, trajectory, purpose)
    return np.array([uniform(key, start + i) for i in range(count)])


@jit
def uniform_table(seed, first, count, purpose, k):
    """Draws 0 … k−1 of the streams of trajectories first … first+count−1 -> (count, k) array."""
    out = np.empty((count, k))
    for j in range(count):
        key = stream_key(seed, first + j, purpose)
        for i in range(k):
            out[j, i] = uniform(key, i)
    return out
