"""The bookkeeping the refilling streams of the lane kernels share (kernels/fabrik_lanes.py,
kernels/fabrik_limited_lanes.py, kernels/ccd_lanes.py, kernels/dls_lanes.py, kernels/dls_general_lanes.py): which
characters a stream works through, a lane's error and the rule that stops its character.

They take the streams' field rows as template arguments; none creates Taichi state.
"""

import taichi as ti

from crowd_ik.kernels import lane_math as lm


@ti.func
def stream_range(slot, stride, n, n_streams):
    """(s, first, end): the stream that iteration `slot` of a kernel's spread loop works on (kernels/work_split.py:
    every stride-th iteration is a stream, the others skip) and its contiguous range [first, end) of n items."""
    s = slot // stride
    chunk = (n + n_streams - 1) // n_streams
    first = s * chunk
    return s, first, ti.min(first + chunk, n)


@ti.func
def lane_error(s, eff_joint: ti.template(), px: ti.template(), py: ti.template(), pz: ti.template(),
               tx: ti.template(), ty: ti.template(), tz: ti.template(), tw: ti.template()):
    """Per lane of stream s: the max over effectors with positive weight tw of |joint position p - target t|."""
    err = ti.Vector.zero(ti.f32, ti.static(px.n))
    for e in range(eff_joint.shape[0]):
        k = eff_joint[e]
        n = lm.norm3(px[s, k] - tx[s, e], py[s, k] - ty[s, e], pz[s, k] - tz[s, e])
        err = ti.select(tw[s, e] > 0.0, ti.max(err, n), err)
    return err


@ti.func
def stop_rule(live, new_err, new_turn, err, turn, it, flat, flat_share, stall_after, max_iterations, tolerance,
              turn_tolerance):
    """One update of the live lanes: it counts it, and a character stops once stall_after updates in a row improved
    neither error by flat_share of itself (stalled), its iterations ran out, or both errors are within their
    tolerances. Returns err, turn, it, flat and the lanes to hand out (pending, 1.0) and still going (live)."""
    going = live > 0.0
    it = it + live
    flat_now = (new_err > err * (1.0 - flat_share)) & (new_turn >= turn * (1.0 - flat_share))
    flat = ti.select(going, ti.select(flat_now, flat + 1.0, 0.0), flat)
    err = ti.select(going, new_err, err)
    turn = ti.select(going, new_turn, turn)
    done = going & ((flat >= stall_after) | (it >= ti.cast(max_iterations, ti.f32))
                    | ((err <= tolerance) & (turn <= turn_tolerance)))
    return err, turn, it, flat, ti.select(done, 1.0, 0.0), ti.select(done, 0.0, live)
