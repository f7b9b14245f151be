"""contour_error_node: tool-tip and tool-orientation contour errors of every control step
(Sencer Eqs. 17-28, core in machine_ctrl/contour/estimation.py), for anyone (recorder, views,
analysis; the servo's contour control estimates its own).

Inputs: /reference (trajectory_msgs/JointTrajectory chunks on the control grid, all axes of
the machine), converted to the reference tool trajectory when a chunk arrives, and
/joint_states (the measured axes of step k). Per state of step k whose reference row is
there (states of steps already done — hw_sim's re-sends — are ignored):

    /contour_error/tool_tip               geometry_msgs/Vector3Stamped  m, frame `workpiece`
    /contour_error/tool_tip_magnitude     std_msgs/Float64              m
    /contour_error/orientation            geometry_msgs/Vector3Stamped  rad (small-angle vector), frame `workpiece`
    /contour_error/orientation_magnitude  std_msgs/Float64              rad

published in that order, stamp = the state's stamp, each while it has a subscriber (as
hw_sim's ground truth; the estimate of every step is computed all the same: the estimator
carries state from step to step, and the diagnostics count every step). Building and
publishing these messages was about half of what the node added to a step of a
single-process graph (bench/RESULTS.md "[5/8] One process: the per-step streams without
DDS"). A step whose estimate is not valid (its
bound on |estimate - true contour error| is above the tolerance: a join, a corner, a reversal,
the last rows of a stop, a path end; machine_ctrl/contour/validity.py, README "Contour error")
is published as NaN in all three components and in the magnitude, the convention of REP 117
for a reading that is not there: the step is still published (a consumer pairing topics by
stamp sees every step) and a consumer that does not check cannot take a wrong number for a
good one. A consumer that needs estimates (a contouring controller) uses only finite ones;
`invalid_tool_tip_steps`, `invalid_orientation_steps` and the last one with its reason are on
/diagnostics. The bound looks at the reference rows up to HORIZON (0.2 s) ahead of the step:
the node computes what the offline core computes as long as the reference is streamed that far
ahead of the states (the trajectory node's 3000 rows: 0.3 s at 10 kHz, not enough on
fts_lathe's 5 us period). Parameters: `machine`, `estimator`
(basic | shifted | compensated; live, from the next step). A state whose reference row has
not arrived waits for it (so start-up timing cannot change what is published); after
MAX_SHIFT worth of steps without it the oldest waiting state is given up. A refused message
is reported and the node keeps running.

States without a reference row are a state of the node, not a flood (:class:`PendingStates`):
states from before the reference began (the machine stepped before the reference source
streamed: paced mode, a late or restarted source) are start-up, counted once
(`steps_before_reference`, one info line) and given up as soon as the reference shows they
precede it; a gap in a reference that had begun is a fault of the stream: one warning with
the reason when it begins, one info line when rows come back, WARN on /diagnostics only
while it lasts (`skipped_steps` and `gaps` keep the counts). Before, both kinds were one
lifetime counter and the status said "steps without reference" for the rest of the run.
"""
from __future__ import annotations

import math
from collections import deque

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from rclpy.node import Node
from std_msgs.msg import Float64

from machine_ctrl import contract, parameters
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.recording.cdr import JointStateData
from machine_ctrl.contour.estimation import MAX_SHIFT, ContourEstimator, ToolTrajectory, tool_reference
from machine_ctrl.contour.validity import machine_tolerances
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.ros.node_common import (main_for, rejections, subscribe_joint_states, subscribe_reference,
                                          use_sim_time, wall_timer)
from machine_ctrl.ros.node_parameters import declare_parameters, machine_parameter


class ContourErrorNode(Node):
    def __init__(self, name: str = 'contour_error', **kwargs):
        super().__init__(name, **kwargs)
        use_sim_time(self, lambda reason: self.rejections.add('clock', reason))
        self.machine = machine_parameter(self)
        method = declare_parameters(self, parameters.CONTOUR_ERROR,
                                    on_change={'estimator': self.on_estimator}).estimator
        self.kinematics = Kinematics.from_config(self.machine)
        try:
            self.estimator = ContourEstimator(self.kinematics, method, machine_tolerances(self.machine))
        except ValueError as exc:
            self.get_logger().fatal(f'parameter estimator: {exc}')
            raise SystemExit(2) from None
        self.clock = ros_io.StepClock.of(self.machine)
        self.trajectory = ToolTrajectory(self.machine.control_period)
        self.history = self.trajectory.horizon + 2     # the rows an estimate may look back at, and 2
        self.invalid = InvalidSteps()
        logger = self.get_logger()
        waiting = int(math.ceil(MAX_SHIFT / self.machine.control_period)) + 2
        self.pending = PendingStates(waiting, logger.warning, logger.info,
                                     lambda reason: self.rejections.add('state', reason))
        self.rejections = rejections(self)
        self.frame = self.machine.workpiece_frame
        self.pubs = [self.create_publisher(kind, topic, ros_io.STEP_QOS) for kind, topic in (
            (Vector3Stamped, contract.CONTOUR_TOOL_TIP.name), (Float64, contract.CONTOUR_TOOL_TIP_MAGNITUDE.name),
            (Vector3Stamped, contract.CONTOUR_ORIENTATION.name), (Float64, contract.CONTOUR_ORIENTATION_MAGNITUDE.name))]
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS.name,
                                              ros_io.qos(contract.DIAGNOSTICS.qos))
        subscribe_reference(self, contract.REFERENCE.name, self.clock, self.machine.axis_names, self.on_reference,
                            lambda reason: self.rejections.add('reference', reason))
        subscribe_joint_states(self, contract.JOINT_STATES.name, self.on_state,
                               lambda reason: self.rejections.add('state', reason), later=True)   # not in the loop
        wall_timer(self, 1.0, self.publish_diagnostics)
        self.get_logger().info(f'ready: {method} estimator')

    def on_estimator(self, method: str) -> None:
        """From the next step: the estimators differ only in their formula (Eqs. 20, 22, 26),
        the state they keep (the direction of travel at rests) is shared."""
        self.estimator.tip.method = method

    def on_reference(self, first: int, q, qd, qdd) -> None:
        self.trajectory.add(first, *tool_reference(self.kinematics, q, qd, qdd))
        self.pending.reference_from(first)
        self.process()

    def on_state(self, msg: JointStateData) -> None:
        try:
            step = self.clock.step_at(msg.sec, msg.nanosec)
            q = ros_io.select(msg, 'position', self.machine.axis_names)
        except ros_io.InvalidMessage as exc:
            self.rejections.add('state', str(exc))
            return
        if self.pending.add(step, q):
            self.process()

    def process(self) -> None:
        """Estimate the waiting states, in step order, as far as their reference rows are here."""
        for step, q in self.pending.ready(self.trajectory):
            self.trajectory.drop_before(step - self.history)
            estimate = self.estimator.update(self.trajectory, step, q)
            self.invalid.add(step, estimate)
            read = [pub.get_subscription_count() > 0 for pub in self.pubs]
            if any(read):
                for pub, message, wanted in zip(self.pubs, self.messages(self.clock.stamp(step), estimate), read):
                    if wanted:
                        pub.publish(message)

    def messages(self, stamp, estimate):
        out = []
        for vector, valid in published(estimate):
            msg = Vector3Stamped()
            msg.header.stamp, msg.header.frame_id = stamp, self.frame
            msg.vector.x, msg.vector.y, msg.vector.z = vector
            out += [msg, Float64(data=math.sqrt(sum(v * v for v in vector)) if valid else math.nan)]
        return out

    def publish_diagnostics(self) -> None:
        pending = self.pending
        values = {'estimator': self.estimator.tip.method, 'last_step': pending.last_step,
                  'estimated_step': pending.estimated_step, 'waiting_states': len(pending),
                  'steps_before_reference': pending.before_reference, 'skipped_steps': pending.skipped,
                  'gaps': pending.gaps, 'buffered_steps': len(self.trajectory),
                  'rejected_messages': self.rejections.count, 'last_rejection': self.rejections.last,
                  **self.invalid.values()}
        problems = pending.gap_since is not None or self.rejections.count
        self.pub_diag.publish(ros_io.diagnostics(
            self.clock.stamp(max(pending.last_step, 0)), self.get_name(),
            DiagnosticStatus.WARN if problems else DiagnosticStatus.OK, pending.state(), values))


def published(estimate):
    """[(tool-tip vector, valid), (orientation vector, valid)] as the node publishes them: an
    invalid estimate as NaN (module docstring)."""
    return [(tuple(float(v) for v in part.vector) if part.valid else (math.nan,) * 3, part.valid)
            for part in (estimate.tool_tip, estimate.orientation)]


class InvalidSteps:
    """Counts of the steps published as NaN, and the last of each, for /diagnostics."""

    def __init__(self):
        self.count = {'tool_tip': 0, 'orientation': 0}
        self.last = {'tool_tip': '', 'orientation': ''}

    def add(self, step: int, estimate) -> None:
        for name, part, unit in (('tool_tip', estimate.tool_tip, 'm'), ('orientation', estimate.orientation, 'rad')):
            if not part.valid:
                self.count[name] += 1
                self.last[name] = f'step {step}: {part.check.reason} (bound {part.check.bound:.3g} {unit})'

    def values(self) -> dict:
        return {'invalid_tool_tip_steps': self.count['tool_tip'], 'last_invalid_tool_tip': self.last['tool_tip'],
                'invalid_orientation_steps': self.count['orientation'],
                'last_invalid_orientation': self.last['orientation']}


class PendingStates:
    """The states waiting for their reference rows, in step order, and what became of those
    that never got one (module docstring). ROS-free: `warn`/`info` take one line each."""

    def __init__(self, history: int, warn, info, refuse=lambda reason: None):
        self.history, self.warn, self.info, self.refuse = history, warn, info, refuse
        self.queue: deque = deque()
        self.last_step = -1                  # newest state taken
        self.estimated_step = -1             # newest state handed out for estimation
        self.first_reference: int | None = None     # first step of the first reference chunk
        self.before_reference = 0            # given up: before the reference began (start-up)
        self.skipped = 0                     # given up: the reference had begun, the row never came
        self.gaps = 0
        self.gap_since: int | None = None    # first step given up in the current gap
        self.gap_steps = 0                   # steps given up in the current gap
        self.skip_candidate = None           # (step, q) of a state far ahead, seen once
        self._started_told = False

    def __len__(self) -> int:
        return len(self.queue)

    def state(self) -> str:
        """The status message: what the node is doing about its reference."""
        if self.gap_since is not None:
            return f'no reference since step {self.gap_since} ({self.gap_steps} steps without it so far)'
        if self.first_reference is None:
            return 'waiting for the reference (never received)' if self.last_step >= 0 else 'waiting for states'
        return 'ok'

    def reference_from(self, first_step: int) -> None:
        if self.first_reference is None:
            self.first_reference = first_step

    def add(self, step: int, q) -> bool:
        """A state; False for one already taken (hw_sim's re-sends) or held back. No reference
        for `history` steps: the oldest waiting state is given up. A state more than one step
        ahead of the newest is held back until it is confirmed — the state of its next step
        follows (states lost on the way, e.g. a queue overrun under load: a real gap, taken
        without a word) or it comes again — and refused (`refuse`, with the reason) when a
        state that is not its successor comes instead: so a stray state stamped in the future
        cannot make the node ignore every real state as older (README "A well-formed state
        stamped more than one step ahead is refused unless it comes again"). The first state
        is taken wherever it is (a node started while the graph runs)."""
        if step <= self.last_step:
            return False
        candidate = self.skip_candidate
        if candidate is not None and step in (candidate[0], candidate[0] + 1):
            if step != candidate[0]:
                self._take(*candidate)            # confirmed by its successor: a real gap
            self._take(step, q)
            return True
        if candidate is not None:                 # not confirmed: it was stray
            self.skip_candidate = None
            self.refuse(f'state of step {candidate[0]} skips ahead of step {self.last_step + 1} '
                        f'(not followed by step {candidate[0] + 1}, nor sent again)')
        if self.last_step >= 0 and step > self.last_step + 1:
            self.skip_candidate = (step, q)
            return False
        self._take(step, q)
        return True

    def _take(self, step: int, q) -> None:
        self.skip_candidate = None
        self.last_step = step
        self.queue.append((step, q))
        if len(self.queue) > self.history:
            self._give_up(self.queue.popleft()[0], 'waited')

    def ready(self, trajectory):
        """The waiting states whose rows `trajectory` holds, in step order; states it shows
        can never get a row (older than its first row) are given up on the way."""
        queue = self.queue
        while queue:
            step = queue[0][0]
            if trajectory.has(step):
                item = queue.popleft()
                if self.gap_since is not None:
                    self.info(f'reference rows back from step {step}: {self.gap_steps} steps from step '
                              f'{self.gap_since} on had none (no contour error published for them)')
                    self.gap_since, self.gap_steps = None, 0
                self.estimated_step = step
                if self.before_reference and not self._started_told:
                    self._started_told = True
                    self.info(f'{self.before_reference} states came before the reference began (step '
                              f'{self.first_reference}): start-up, no contour error for them')
                yield item
            elif len(trajectory) and step < trajectory.first:
                self._give_up(queue.popleft()[0], 'precedes')
            else:
                return

    def _give_up(self, step: int, why: str) -> None:
        if self.first_reference is None or step < self.first_reference:
            self.before_reference += 1
            return
        self.skipped += 1
        self.gap_steps += 1
        if self.gap_since is None:
            self.gap_since = step
            self.gaps += 1
            reason = (f'waited {self.history} steps for it' if why == 'waited'
                      else 'the reference stream jumped past it')
            self.warn(f'no reference row for step {step} ({reason}): its contour error is not published; '
                      f'one line per gap, counted as skipped_steps on {contract.DIAGNOSTICS.name}')


main = main_for(ContourErrorNode)

if __name__ == '__main__':
    raise SystemExit(main())
