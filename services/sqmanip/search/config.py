"""Configuration of the shelf search (Ch. 5.3-5.6, C.2, C.3): the methods of Table 5.1 and the
5.6.2 ablations as options, with the thesis' constants as defaults.

Values the thesis does not state are marked "(ours)": the pose-grid resolution, ``alpha`` and
``gamma``, the render resolution and samples per ray, the ``f_c`` shrink.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

from sqmanip.errors import ValidationError

Method = Literal["search_for_grasp", "search_and_grasp"]
"""5.3: search-for-grasp minimises (5.4.6) with J = sum f + alpha f (1 - g); search-and-grasp
minimises sum f until the target is seen, then 1 - g(x*)."""
ActionSet = Literal["both", "push", "pick_and_place"]
"""5.6.2 ablation: sample from I_p + I_g, I_p only or I_g only."""


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    method: Method = "search_for_grasp"
    actions: ActionSet = "both"
    # --- pose set X (5.3, 5.6.3) ---
    resolution: float = 0.02
    """Pose grid spacing on the shelf floor (m) (ours; the thesis gives none)."""
    n_theta: int = 8
    """Yaws in [0, pi) of the SE(2) grid for a box target (ours)."""
    # --- existence f (C.2) ---
    render_scale: float = 1.0 / 7.0
    """Depth images for f_d are rendered at this fraction of the camera resolution; 1280 x 720 / 7
    is 183 x 103 = 18,849 pixels, about the thesis' WH = 18,564 (C.2 cost)."""
    n_ray_samples: int = 16
    """Samples per ray chord for the soft depth (C.2.7-C.2.8) (ours)."""
    sharpness: float = 1000.0
    """p of the occupancy sigmoid (C.2.6)."""
    tau: float = 100.0
    """Transmittance scale (C.2.7)."""
    t_near: float = 0.0
    t_far: float = 1.5
    mse_threshold: float = 0.001
    """f_d(x) = 0 when the mean squared difference between the depth rendered with and without
    the target at x, over the target's own pixels (those whose ray meets it), reaches this (C.2;
    the mean over the target's pixels, not the whole image, see :mod:`.existence`)."""
    found_pixels: int = 100
    """f_d(x) = 0 also when more than this many camera pixels would see the target at x: the
    5.5.1 detection criterion, i.e. the target would have been found there."""
    seen_margin: float = 0.02
    """A pixel sees the target when its depth with the target is this much (m) nearer than
    without: differences below it are left to the MSE test (recognition error tolerance) (ours)."""
    seen_fraction: float = 0.25
    """The episode runner remembers a pose as empty once the camera's own depth image showed
    the target's place there in plain view on this share of its footprint
    (:meth:`.existence.ExistenceModel.seen_empty`), and ``f`` stays 0 there (the non-increasing
    uncertainty of 5.4.2 across real steps, ours). Above 1 nothing is remembered: each step's
    ``f`` comes from its own observation only. Lower shares find the target more often but do
    not grasp it more often (R-Search-for-Grasp at 6 and 8 objects, saved seed-300/500
    scenarios: 0.15 found 46 of 54 against 44 and grasped 34 either way; 0.1, seed 500 only,
    found 19 of 24 against 16 and grasped 15 against 16;
    ``benchmarks/results/search_r_sfg_6_8_seed*_seen1*.json``)."""
    n_target_points: int = 512
    """n_o target surface points for f_c (C.2.10)."""
    fc_shrink: float = 0.005
    """The target is shrunk by this (m) for f_c only: it stands on the floor board (a contact, not
    a collision) and, with the grid spacing, 'can exist near x' (5.3) (ours)."""
    object_tolerance: float = 0.01
    """Against the objects (not the shelf) f_c shrinks the target by this much more (m): a
    recognized object's hidden back is an estimate, and behind an occluder is where the target
    stands. With 0, the target's true pose had f = 0 in 14 of 40 start scenes (R-, scenario
    seed 100): the planner ruled it out and pushed into it (ours; see the issue note)."""
    # --- graspability g (C.3) ---
    grasp_tilt_deg: float = 20.0
    grasp_max_width: float = 0.075
    """Widest antipodal grasp (C.3: 7.5 cm, the Franka opens 8 cm), of the target and of the
    objects the planner picks. Recognized boxes run wide (``benchmarks.search_recognition``): of
    279 objects in 40 saved scenes, 21 were recognized 7.5 to 8 cm wide, 14 of them truly 7.5 cm
    or less, so a blocker can be left unpickable (scenario seed 8310). Picking objects up to
    7.75 cm (the target kept at 7.5 cm) grasped 71 of 120 fresh scenes against 70, paired: 33
    against 30 at 8 objects, 38 against 40 at 6
    (``benchmarks/results/search_r_sfg_*obj_seed1{1,3}00_30x_pickwidth.json``), so both keep
    7.5 cm."""
    approach_distance: float = 0.30
    n_gripper_points: int = 2048
    """n_gr points on the afterimage of the gripper and links 6-7 (C.3.11)."""
    grasp_yaws_deg: tuple[float, ...] = (-80.0, -60.0, -40.0, -20.0, 0.0, 20.0, 40.0, 60.0, 80.0)
    """Approach yaws about the vertical for a round target (a cylinder can be grasped from any
    side, 5.6.3). The C.3 rule gives each yaw's facing side and, within ``facing_angle_deg``,
    the side 90 degrees from it, so these nine give 17 approach directions 10 degrees apart;
    with ``grasp_heights`` N_gr = 51, above the thesis' 10 to 30 (f and g over the grid still
    take about 6 and 10 ms, ``benchmarks.search_functions``). The side yaws matter on a
    crowded shelf: a target hemmed in front is often reachable only past a neighbour's flank.
    Against +-40 degrees and 4 heights (7 directions, N_gr = 28), R-Search-for-Grasp on the
    saved seed-300/500 scenarios went from 64 to 73 of 108 (11 episodes won, 2 lost)."""
    grasp_heights: int = 3
    floor_clearance: float = 0.02
    """Target grasps whose open gripper comes closer than this to the floor are dropped, and
    executed actions keep the gripper this far from the floor (ours)."""
    grasp_voxel: float = 0.005
    """Target voxel size (m) of the object occupancy in the fast afterimage test; the actual
    size divides ``resolution`` (ours)."""
    facing_angle_deg: float = 90.0
    """Side grasps must approach within this of +x (into the shelf, from the robot); 90 keeps
    every yaw of ``grasp_yaws_deg`` and the picks of other objects from their flanks (ours)."""
    # --- objective and MPC (5.4.3-5.4.7) ---
    alpha: float = 1.0
    """Weight of f (1 - g) in J (5.4.7) (ours; 5.6.4 sweeps it). With 3, R-Search-for-Grasp at 6
    and 8 objects on the saved seed-300/500 scenarios changed no episode's outcome (34 of 54
    grasped either way, ``benchmarks/results/search_r_sfg_6_8_seed*_alpha3.json``)."""
    gamma: float = 0.9
    """Discount of (5.4.6) (ours)."""
    horizon: int = 3
    """M (5.4.3)."""
    n_sequences: int = 30
    """Sampled action sequences per decision (5.4.4)."""
    max_steps: int = 10
    """T (5.4.3): the episode runner stops after this many actions."""
    # --- actions (5.4.4) ---
    push_tilt_deg: float = 30.0
    push_gap: float = 0.01
    push_distances: tuple[float, ...] = (0.05, 0.10, 0.15)
    upright_push: bool = True
    """Where the hand of 5.4.4 has no room beside an object, push with it turned on its side
    (:meth:`.actions.ActionSampler.push_poses`): its 20 cm palm upright, 6.3 cm across the
    push. In the simulator the level hand needs about 15 cm between an object and a side
    board, the upright one 9.5 cm; between objects it fits where the level palm would reach
    over the neighbour (ours). R-Search-for-Grasp on the seed-2700 scenes, paired against
    ``False`` (the committed run of the planner before): 25/21/21/13 of 30 grasped at 2/4/6/8
    objects against 24/20/19/12 (11 won, 6 lost); on the seed-2500 scenes 21/18 at 6/8
    objects against 17/17 (9 won, 4 lost; 79 upright pushes executed in the 60 episodes); on
    the seed-2300 scenes 25/28 at 2/4 objects against 23/28 (4 won, 2 lost). Over the 240
    paired episodes 172 against 160, 24 won and 12 lost. The simulator refused more actions
    on 2700 and 2500 (215 against 135: upright pushes whose wrist meets a board or needs a
    joint flip; a refusal costs a re-plan, not a step)
    (``benchmarks/results/search_r_sfg_*_30x_upright.json``)."""
    keep_out_margin: float = 0.01
    """Where the target may stand (``f = 1``) is kept clear of pushed objects, the pusher and
    placed objects with this margin (m) beyond the target's radius: the target stands anywhere
    within half a grid cell of a pose with ``f = 1``, and a push that grazes it shoves it
    deeper, out of every grasp (ours)."""
    action_tolerance: float = 0.005
    """The gripper checks of the sampled pushes and picks (the closed hand at a push start,
    the afterimage of a pick and of its place) test the other objects with their level half
    sizes less this (m); heights are kept. Recognized boxes run wide along both level axes
    (the narrower one by 0.65 cm on average over 121 boxes of 40 saved scenes, network and
    fitter alike) while their heights are right, so on a crowded shelf they closed the last
    gaps a hand fits in, and episodes ended with "no valid action" while the target was in
    view (scenario seeds 9111, 9312). The robot checks each action against the objects as
    they are and refuses a colliding one without a step spent (up to
    :attr:`~sqmanip.search.episode.EpisodeRunner.max_replans` per step). The O- methods'
    true shapes shrink too, as for ``object_tolerance`` (ours). R-Search-for-Grasp, paired
    against 0 on fresh scenes: 8 objects 69 of 120 grasped against 60 (17 won, 8 lost), 6
    objects 62 of 90 against 58 (11 won, 7 lost), 4 and 2 objects 23 and 26 of 30 against 22
    and 26; "no solution" endings at 6 and 8 objects 20 against 27, refusals 150 against 160
    (``benchmarks/results/search_r_sfg_*_tolerance.json``). The gain came from the seed-1100
    and 1300 sets the idea was found on (8 objects 38 against 30); on the sets made after it
    (1500, 1700) it is 49 against 48 at 6 and 8 objects together, so it is a small one."""
    last_resort_tolerances: tuple[float, ...] = (0.015, 0.03)
    """When a decision finds no valid action, which ends the episode, it tries again, first
    picking objects from their first grasp that clears the floor (not just their first
    grasp), then with ``action_tolerance`` loosened to each of these in turn and pushes
    starting ``last_resort_push_gap`` from the object. The robot still checks each action
    against the objects as they are and refuses a colliding one. Only episodes that would end
    with "no valid action" change (ours). R-Search-for-Grasp (before the slide rule of
    :meth:`.actions.ActionSampler.push_distances`): of the 25 committed episodes
    (330, 2 to 8 objects, seed sets 1100 to 1700) that ended so, 7 grasped the target instead
    (2 objects 0 of 3, 4 objects 1 of 5, 6 objects 3 of 7, 8 objects 3 of 10; replayed with
    ``benchmarks.search --only``, ``benchmarks/results/search_r_sfg_seed1*_30x_last_resort.json``);
    these clearances were picked on those 25 (1.5 cm with a 3 mm gap, or 3 cm with none,
    alone turned 6 each). On the fresh seed-1900 sets it was used in 13 of 120 episodes and 5
    of them grasped (``search_r_sfg_*obj_seed1900_30x_last_resort.json``). What is left is
    mostly an object wider than the 7.5 cm pick limit against a side wall, or two in a
    corner: no push start beside it and no pick."""
    last_resort_push_gap: float = 0.003
    """``push_gap`` of the loosened passes of ``last_resort_tolerances`` (m) (ours)."""
    risk_weight: float = 0.0
    """When no push keeps out of where the target may stand (the fallback pass of
    :meth:`SearchPlanner.decide`), a push whose hand's way in or whose pushed object's slide
    meets a share ``p`` of those poses costs ``risk_weight * p * J_0`` more (ours; 0: the
    fallback pushes are ranked by the objective alone): a shoved target tends to end deeper or
    against a wall, out of every grasp. Off by default: with recognized shapes no setting
    measured better than 0 (``benchmarks.search``, 100 paired episodes; see the issue note)."""
    escalate_when_stuck: bool = True
    """When no sampled sequence that keeps out of where the target may stand is predicted to
    gain anything (the best cost of (5.4.6) is 0), the pushes that may sweep there are sampled
    as well and compete by the objective, as they do when no safe action exists (ours). Traced
    cause: the safe actions were pushes and picks of bystanders that change nothing, so the
    decision kept choosing them and the push of the occluder that would reveal the target
    never came (scenario seeds 3925, 5923: 8 and 4 decisions in a row at cost 0 until the
    step limit). R-Search-for-Grasp, paired on fresh scenes against ``False``: seed 2300, 2
    and 4 objects, 23 and 28 of 30 grasped against 21 and 27 (3 won, 0 lost); seed 2500, 6 and
    8 objects, 17 and 16 against 17 and 17 (0 won, 1 lost: an episode grasped at step 10 by
    the old rule) (``benchmarks/results/search_r_sfg_*_seed2{3,5}00_30x*.json``). Replayed on
    the seed-1900 (2, 4 objects; where 3925 and 5923 were traced) and 2100 (6, 8) sets against
    the committed runs: 21/19/20/18 of 30 against 22/18/20/18 (2 won, 2 lost;
    ``..._seed{1900,2100}_30x_stuck.json``). Over all 240 paired episodes: 5 won, 3 lost,
    within noise. Kept for the steps it saves: over the 157 episodes both grasped, 3.31
    actions to the grasp against 3.44 (11 shorter, 2 longer)."""
    place_resolution: float = 0.03
    """Spacing of the candidate place spots on the floor (m) (ours)."""
    max_place_spots: int = 64
    """At most this many free spots are kept per object (random subset) (ours)."""
    seed: int = 0

    def __post_init__(self) -> None:
        if self.method not in ("search_for_grasp", "search_and_grasp"):
            raise ValidationError(
                f"method must be 'search_for_grasp' or 'search_and_grasp', got {self.method!r}"
            )
        if self.actions not in ("both", "push", "pick_and_place"):
            raise ValidationError(
                f"actions must be 'both', 'push' or 'pick_and_place', got {self.actions!r}"
            )
        for name in ("horizon", "n_sequences", "max_steps", "n_ray_samples", "n_target_points"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValidationError(f"{name} must be an integer >= 1, got {v!r}")
        if not (0.0 < self.gamma <= 1.0):
            raise ValidationError(f"gamma must be in (0, 1], got {self.gamma!r}")
        if not (math.isfinite(self.alpha) and self.alpha >= 0):
            raise ValidationError(f"alpha must be finite and >= 0, got {self.alpha!r}")
        if not (isinstance(self.found_pixels, int) and self.found_pixels >= 0):
            raise ValidationError(
                f"found_pixels must be an integer >= 0, got {self.found_pixels!r}"
            )
        if not (math.isfinite(self.object_tolerance) and self.object_tolerance >= 0):
            raise ValidationError(
                f"object_tolerance must be finite and >= 0, got {self.object_tolerance!r}"
            )
        if not (math.isfinite(self.action_tolerance) and self.action_tolerance >= 0):
            raise ValidationError(
                f"action_tolerance must be finite and >= 0, got {self.action_tolerance!r}"
            )
        if not all(math.isfinite(t) and t >= 0 for t in self.last_resort_tolerances):
            raise ValidationError(
                "last_resort_tolerances must be finite and >= 0, "
                f"got {self.last_resort_tolerances!r}"
            )
        if not (math.isfinite(self.last_resort_push_gap) and self.last_resort_push_gap >= 0):
            raise ValidationError(
                f"last_resort_push_gap must be finite and >= 0, got {self.last_resort_push_gap!r}"
            )
        if not (math.isfinite(self.keep_out_margin) and self.keep_out_margin >= 0):
            raise ValidationError(
                f"keep_out_margin must be finite and >= 0, got {self.keep_out_margin!r}"
            )
        if not (math.isfinite(self.risk_weight) and self.risk_weight >= 0):
            raise ValidationError(f"risk_weight must be finite and >= 0, got {self.risk_weight!r}")
        if not (math.isfinite(self.seen_margin) and self.seen_margin >= 0):
            raise ValidationError(f"seen_margin must be finite and >= 0, got {self.seen_margin!r}")
        if not (math.isfinite(self.seen_fraction) and self.seen_fraction > 0):
            raise ValidationError(
                f"seen_fraction must be finite and > 0, got {self.seen_fraction!r}"
            )
        if not (0.0 < self.render_scale <= 1.0):
            raise ValidationError(f"render_scale must be in (0, 1], got {self.render_scale!r}")
        if self.n_gripper_points < 16:
            raise ValidationError(f"n_gripper_points must be >= 16, got {self.n_gripper_points!r}")
        if not self.push_distances or min(self.push_distances) <= 0:
            raise ValidationError(f"push_distances must be positive, got {self.push_distances!r}")
