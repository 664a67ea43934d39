"""The planner's tuning: every constant of its rules, in one frozen record.

What an operator sets (radius, margin, speeds, acceleration, latency, memory, search times)
is the ``avoidance`` configuration section and the ``AVD_*`` parameters; this is the rest,
the shape of the rules themselves, measured in simulation and SITL. A test or an experiment
passes its own ``Tuning`` to the planner; nothing patches a module constant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Tuning:
    """The planner's constants.

    Attributes:
        mu_goal: Cost per radian a way turns from the goal's direction.
        mu_heading: Cost per radian a way turns from the vehicle's heading.
        mu_previous: Cost per radian a way turns from the way chosen last cycle.
        mu_obstructed: Cost of a way blocked at once, falling to nothing for one that runs
            clear (to the goal, or as far as the sensors see): gaps and ends are aimed for
            before the vehicle is at the wall.
        commitment_cost: Extra cost of the side of the goal direction the vehicle is not
            committed to while going round something (no flipping between the sides of a
            pole); three half-turns' worth of goal cost.
        max_side_changes: Side changes allowed while going round one obstacle; a third would
            be dithering.
        altitude_gain_per_s: Climb rate per metre of altitude error.
        arrived_altitude_m: Within this of the goal's altitude (and inside the acceptance
            radius) the goal is reached.
        buffer_m: Turning room kept beyond the clearance when choosing a way, at a hover.
        buffer_s: And per m/s of speed (the vehicle lags its setpoint in a turn).
        slow_for_gap_m_s: Speeds at which the turning buffer lets a way open that is too
            narrow at full speed (the faster first).
        passing_deg: A way this much nearer the goal's direction than the one flown is worth
            slowing down for.
        onward_deg: Ways within this of the goal's direction go onward; beyond it the vehicle
            backs out.
        back_deg: Ways at least this far from the goal's direction lead straight back.
        enter_m: A way becomes admissible when it is free this far (or the acceptance radius,
            if that is more).
        leave_m: A way stays admissible down to this much free distance: the speed law
            brings the vehicle up to its margin and it stops there, not half a metre short.
        straight_deg: Ways within this of the vehicle's velocity need no turning room.
        straight_buffer_m: The room kept on them instead.
        goal_snap_deg: A chosen way within this of an open goal direction is the goal's.
        yaw_gain_per_s: Yaw rate per radian of heading error.
        pause_ns: A gap this long between decisions means planning was paused (its timers
            restart).
        inside_slack_m: Within the clearance of a point, the ways that bring the vehicle this
            much nearer close; and the back-away starts beyond it.
        toward_deg: Ways this close to the side of what is within the clearance bring the
            vehicle nearer.
        one_sided: How one-sided the points within the clearance must be for that side to
            count.
        back_away_gain_per_s: Speed away from what the vehicle is within the clearance of, m/s
            per metre inside.
        back_away_max_m_s: At most this fast (ArduPilot's ``AVOID_BACKUP_SPD`` default).
        back_away_growth_per_s2: While the vehicle stays inside the clearance, its back-away
            grows by this many m/s per metre inside per second.
        back_away_fade_s: Outside the clearance, what the back-away grew by fades with this
            time constant.
        back_away_step_s: The longest step the growth integrates over.
        back_out_after_ns: A way back must stay the choice this long before the vehicle turns
            back (it brakes first).
        turn_back_m_s: Slower than this, turning back needs no braking first.
        turn_back_deg: A way this far from the vehicle's velocity turns it back on itself.
        overspeed_gain: Extra braking, m/s of setpoint per m/s the vehicle is faster than the
            plan.
        overspeed_slack_m_s: Faster than the plan by at most this is ordinary lag: no extra
            braking.
        drift_band_m: Drift toward what is within the clearance plus this is checked (about a
            second of the drift seen in SITL before it would reach the clearance).
        drift_slack_m_s: Disagreement between the track and the reported velocity up to this
            is noise.
        closing_ramp_m_s: Over this much planned speed toward a near side the closing brake's
            slack grows from the drift's noise to the overspeed brake's.
        drift_jump_m_s: A disagreement beyond this is a position reset, not a drift: a hold
            sends nothing for it.
        drift_slowing: While the positions drift toward a near obstacle, the speed falls by
            this share of the maximum speed per ``back_away_max_m_s`` of drift.
        drift_slowest: The drift never slows the vehicle below this share of its maximum.
        autopilot_response_s: Time an autopilot's velocity controller takes to act on a new
            setpoint (part of the latency).
        look_margin_m: Beyond the stopping distance at full speed (plus this), nothing unseen
            matters yet.
    """

    mu_goal: float = 5.0
    mu_heading: float = 2.0
    mu_previous: float = 2.0
    mu_obstructed: float = 5.0
    commitment_cost: float = 3.0 * math.pi * 5.0
    max_side_changes: int = 2
    altitude_gain_per_s: float = 1.0
    arrived_altitude_m: float = 0.5
    buffer_m: float = 0.25
    buffer_s: float = 0.15
    slow_for_gap_m_s: tuple[float, ...] = (1.0, 0.5)
    passing_deg: float = 30.0
    onward_deg: float = 100.0
    back_deg: float = 170.0
    enter_m: float = 1.0
    leave_m: float = 0.4
    straight_deg: float = 5.0
    straight_buffer_m: float = 0.25
    goal_snap_deg: float = 5.0
    yaw_gain_per_s: float = 2.0
    pause_ns: int = 1_000_000_000
    inside_slack_m: float = 0.05
    toward_deg: float = 88.0
    one_sided: float = 0.5
    back_away_gain_per_s: float = 2.0
    back_away_max_m_s: float = 0.75
    back_away_growth_per_s2: float = 2.0
    back_away_fade_s: float = 1.0
    back_away_step_s: float = 0.25
    back_out_after_ns: int = 300_000_000
    turn_back_m_s: float = 0.5
    turn_back_deg: float = 100.0
    overspeed_gain: float = 1.0
    overspeed_slack_m_s: float = 0.25
    drift_band_m: float = 1.0
    drift_slack_m_s: float = 0.1
    closing_ramp_m_s: float = 0.25
    drift_jump_m_s: float = 1.5
    drift_slowing: float = 0.5
    drift_slowest: float = 0.5
    autopilot_response_s: float = 0.2
    look_margin_m: float = 1.0

    def buffer_at_m(self, speed_m_s: float) -> float:
        """The turning buffer at a speed."""
        return self.buffer_m + self.buffer_s * speed_m_s


DEFAULT = Tuning()
"""The tuning every planner uses unless given another."""
