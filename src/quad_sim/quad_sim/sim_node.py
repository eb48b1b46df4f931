"""sim_node: the simulated vehicle on the ROS graph (docs/quad_sim.md), wired to ROS-free rules.

lockstep: publish odom then /clock at t_k, wait for the setpoints of t_k and for the lockstep_followers
(quad_common.ros.lockstep), advance lockstep_period_s; the rules (setpoints taken or refused, deadlines, a lost
controller, re-publication for late joiners, when a step may advance, the drain at a stop) are
quad_sim.lockstep_policy's. On SIGINT/SIGTERM, or at duration_s, the loop stops advancing, publishes its final counts
on diagnostics (quad_sim.sim_diagnostics) and drains the followers.
realtime: a wall-clock timer at odom_rate_hz advances the simulation to rtf * elapsed wall time; each vehicle is
held where it starts (time runs, no physics) until its first setpoint, and its vehicle/engaged goes true only then:
a controller that comes late (its /clock late) finds the vehicle where it started, and re-bases a plan whose start
has passed to its engagement.
fleet (vehicle_names set, quad_sim.parameters): one Simulator per named vehicle, each with its topics under its
name (cf1/odom, cf1/cmd/attitude_thrust, ... and its frame cf1/base_link), stepped together under one /clock: step
k waits for every vehicle's setpoint, vehicle-vehicle contacts (robot radii) are events like obstacle collisions
(quad_sim.vehicle_contact), and a vehicle whose controller died lands by its own failsafe while the others fly on.
"""

import time

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from std_srvs.srv import Trigger

try:  # not among the PyPI ROS wheels; present on every machine with ROS 2 installed
    from tf2_msgs.msg import TFMessage
except ImportError:
    TFMessage = None

from quad_common import contract
from quad_common.paths import resolve_config
from quad_common.ros import lockstep
from quad_common.ros.hot_path import HotPathExecutor
from quad_common.ros.node_main import run_node
from quad_common.ros.ros_params import ParameterSet
from quad_common.vehicle import load_vehicle
from quad_common.world import load_world
from quad_sim import lockstep_policy as policy
from quad_sim.disturbances import load_profile
from quad_sim.mocap import MocapConfig
from quad_sim.parameters import MOCAP_FIELDS, SPECS, fleet_layout
from quad_sim.simulated_vehicle import SimulatedVehicle, stamp_of
from quad_sim.simulator import SimulationStopped, Simulator
from quad_sim.vehicle_contact import VehicleContacts

NAME = 'sim_node'


class SimNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NAME, **kwargs)
        self.params = ParameterSet(self, SPECS)
        p = self.params
        world = load_world(self._config(p['world'], 'world')) if p['world'] else None
        profile = load_profile(self._config(p['disturbances_file'], 'disturbances_file'), p['disturbances'])
        fleet = fleet_layout(p)
        self.mocap_config = MocapConfig(**{f: p[f'mocap_{f}'] for f in MOCAP_FIELDS})
        sims = []
        files_param = 'vehicle_files' if p['vehicle_files'] else 'vehicle'
        for k, (_, vehicle_file, position, radius_m) in enumerate(fleet):
            vehicle = load_vehicle(self._config(vehicle_file, files_param), plant=p['plant'] or None)
            sims.append(Simulator(vehicle, physics_rate_hz=p['physics_rate_hz'], initial_position=position,
                                  initial_yaw=p['initial_yaw'], disturbances=profile, world=world,
                                  robot_radius_m=radius_m, seed=(p['seed'] + k) % 2**31,
                                  setpoint_timeout_s=p['setpoint_timeout_s']))
        self.sim = sims[0]   # the time base: every vehicle's simulator is stepped with it
        self.sim.warm_up()
        try:
            self.steps_per_period = self.sim.steps_in(p['lockstep_period_s'])
        except ValueError as exc:
            raise ValueError(f'lockstep_period_s: {exc}') from None
        self.followers = [f.strip() for f in p['lockstep_followers'].split(',') if f.strip()]
        c = contract
        pace = (lambda topic: lockstep.PACED) if self.followers else c.qos  # followers: paced, deep history
        self.clock_pub = self.create_publisher(ClockMsg, c.CLOCK, pace(c.CLOCK))
        self.tf_pub = self.create_publisher(TFMessage, c.TF, c.qos(c.TF)) if TFMessage else None
        if TFMessage is None:
            self.get_logger().warn('tf2_msgs is not installed here: /tf is not published (odom carries the pose)')
        self.sensor_period_ns = int(round(1e9 / p['sensor_rate_hz'])) if p['sensor_rate_hz'] > 0 else 0
        named = bool(p['vehicle_names'])
        self.vehicles = [SimulatedVehicle(self, name, sim, f'{name}/' if named else '', pace)
                         for (name, *_), sim in zip(fleet, sims)]
        self.contacts = VehicleContacts([v.name for v in self.vehicles], sims, [r for *_, r in fleet])
        self.hot_subscriptions = [v.setpoint_sub for v in self.vehicles]
        self.acks = policy.Followers(self.followers)
        # called with the executor at a stop, once the final counts are published and before the wait for the
        # followers: a recorder in this process (quad_bringup.running.node_host) takes its queue and closes its bag
        self.at_final_counts = []
        # called after each step's odometry is published (re-published too), and while the loop waits for its
        # followers: a recorder in this process served once a step, not by the executor's every pass
        # (quad_bringup.running.node_host)
        self.each_step = []
        for follower in self.followers:
            self.hot_subscriptions.append(self.create_subscription(
                ClockMsg, lockstep.ack_topic(follower),
                lambda msg, f=follower: self.acks.ack(f, msg.clock.sec * 1_000_000_000 + msg.clock.nanosec),
                lockstep.ACK))
        self.stop_requested = lambda: False  # main() replaces it with its signal flag
        self.hot_subscriptions += [v.reference_sub for v in self.vehicles if v.reference_sub is not None]
        self.hot_timers = []
        self.create_service(Trigger, 'reset', self._on_reset)
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._reset_bookkeeping()
        what = (f'{sims[0].vehicle.name} at {list(fleet[0][2])}' if not named else
                f'{len(sims)} vehicles ({", ".join(v.name for v in self.vehicles)})')
        self.get_logger().info(
            f'{p["mode"]}: {what}, {p["physics_rate_hz"]:g} Hz physics, '
            f'disturbances {profile.name}, world {p["world"] or "none"}')

    def hot_entities(self):
        """The lockstep's per-step entities (quad_common.ros.hot_path): every vehicle's setpoints, the followers'
        acknowledgements, the realtime tick."""
        return self.hot_subscriptions, self.hot_timers

    def _config(self, path, name):
        try:
            return resolve_config(path)
        except FileNotFoundError as exc:
            raise ValueError(f'{name} = {path!r}: {exc}') from None

    def _reset_bookkeeping(self):
        for v in self.vehicles:
            v.reset_bookkeeping()
        self.contacts.reset()
        self.run_clock = policy.RunClock(time.monotonic(), self.sim.time_ns)

    # --- inputs ------------------------------------------------------------------------------------------

    def _on_reset(self, request, response):
        for v in self.vehicles:
            v.sim.reset()
        self._reset_bookkeeping()
        response.success, response.message = True, 'simulation reset to its initial state; time restarts at 0'
        self.get_logger().info(response.message)
        return response

    # --- outputs -----------------------------------------------------------------------------------------

    def publish_step(self, vehicles=None):
        """Every vehicle's odom and then /clock at the current sim time (contract order); then its sensors and
        diagnostics when due (after /clock: the controller's tick does not wait for them). vehicles: only these
        odometries (a re-publication for controllers that joined late). Realtime: /clock first, as no tick waits
        for odometry there, and an odom that arrives before its /clock is ahead of the controller's clock by a
        tick's worth of sim time (more than one period at rtf > 1 or a late tick): refused."""
        time_ns = self.sim.time_ns
        stamp = stamp_of(time_ns)
        clock_first = self.params['mode'] == 'realtime'
        if clock_first:
            self.clock_pub.publish(ClockMsg(clock=stamp))
        for v in self.vehicles if vehicles is None else vehicles:
            v.publish_odometry(time_ns)
        if not clock_first:
            self.clock_pub.publish(ClockMsg(clock=stamp))
        for v in self.vehicles:
            v.publish_after_clock(time_ns, stamp)

    def publish_diagnostics(self):
        for v in self.vehicles:
            v.publish_diagnostics()

    def real_time_factor(self) -> float:
        return self.run_clock.real_time_factor(time.monotonic(), self.sim.time_ns)

    def advance(self, steps):
        t0_s = self.sim.time_s
        self.run_clock.advancing(time.monotonic(), self.sim.time_ns, time.process_time())
        for v in self.vehicles:
            v.advance(steps)
        if len(self.vehicles) > 1:
            self.contacts.step(t0_s, steps * self.sim.step_ns * 1e-9)

    # --- modes -------------------------------------------------------------------------------------------

    def running(self) -> bool:
        return rclpy.ok(context=self.context) and not self.stop_requested()

    def _ended(self) -> bool:
        end_s = self.params['duration_s']
        return end_s > 0 and self.sim.time_s >= end_s - 1e-9

    def run_lockstep(self, executor):
        """The lockstep loop (see the module docstring); returns when rclpy shuts down, a stop is requested or
        duration_s is reached."""
        lag_ns = lockstep.FOLLOWER_LAG_STEPS * self.steps_per_period * self.sim.step_ns
        while self.running():
            self.publish_step()
            self._each_step()
            t_k = self.sim.time_ns
            follower_ns = policy.Followers.step_target_ns(t_k, lag_ns)
            waited, behind = time.monotonic(), self.acks.behind(follower_ns)
            self._await_followers(executor, follower_ns)
            now = time.monotonic()
            self.run_clock.waited('followers', now - waited, t_k, behind)
            if self._ended():
                break
            waiting = self._await_setpoints(executor, t_k)
            self.run_clock.waited('setpoints', time.monotonic() - now, t_k, [v.name for v in waiting])
            if self.sim.time_ns != t_k:  # reset while waiting
                continue
            if not self.running():
                break
            if policy.may_advance(((v.lockstep.setpoint_stamp_ns, v.lockstep.setpoints_received,
                                    v.controller_present) for v in self.vehicles), t_k):
                self.advance(self.steps_per_period)
        if self.run_clock.stepping:
            sim_s, wall_s, cpu_s = self.run_clock.summary(time.monotonic(), self.sim.time_ns, time.process_time())
            self.get_logger().info(f'lockstep: stepped {sim_s:.3f} s of {len(self.vehicles)} vehicle(s) in '
                                   f'{wall_s:.3f} s ({sim_s / max(wall_s, 1e-9):.2f}x real time; this process '
                                   f'{cpu_s:.3f} s of CPU)')
            for what, (wait_s, t_ns, who) in self.run_clock.longest.items():
                self.get_logger().info(f'lockstep: longest wait for {what} {wait_s * 1e3:.1f} ms at t = '
                                       f'{t_ns * 1e-9:.3f} s ({", ".join(who) or "none behind at its start"})')
        self.drain(executor)

    def _each_step(self):
        for call in self.each_step:
            call()

    def _await_setpoints(self, executor, t_k: int) -> list:
        """Spin until every vehicle has a setpoint stamped >= t_k or its wait (policy.setpoint_timeout_s) ran out,
        re-publishing the odometry of those without a first setpoint (policy.SetpointWait). Returns the vehicles
        it waited for (those without one at its start)."""
        now = time.monotonic()
        deadlines = {v: now + v.lockstep.timeout_s(self.params['lockstep_timeout_s'], v.has_setpoint_publisher)
                     for v in self.vehicles}
        waited_for = [v for v in self.vehicles if v.lockstep.setpoint_stamp_ns < t_k]
        wait = policy.SetpointWait(waited_for, deadlines, now)
        while wait.waiting and self.running():
            now = time.monotonic()
            for v in wait.expire(now):
                if v.lockstep.missed_deadline():
                    self.get_logger().warn(
                        f'{v.name}: ' * bool(v.prefix) + f'no setpoint for t = {t_k * 1e-9:.3f} s within '
                        f'lockstep_timeout_s: each step now waits {policy.LOST_STEP_TIMEOUT_S} s at most (the '
                        'failsafe lands the vehicle) until one arrives')
            if not wait.waiting:
                break
            starting = [v for v in wait.waiting if v.lockstep.setpoints_received == 0]
            if starting and wait.republish_due(now):  # for nodes that joined late
                self.publish_step(starting)
                self._each_step()   # a long wait's re-publications taken as they come
            executor.spin_once(timeout_sec=wait.wake_in_s(now))
            wait.answered(lambda v: v.lockstep.setpoint_stamp_ns >= t_k)
        return waited_for

    def _await_followers(self, executor, stamp_ns):
        """Spin until every follower has acknowledged odometry stamped >= stamp_ns or a stop comes
        (policy.FollowerWait: the step re-published until a setpoint comes, a warning naming the ones behind)."""
        wait = policy.FollowerWait(time.monotonic())
        while (behind := self.acks.behind(stamp_ns)) and rclpy.ok(context=self.context) and not self.stop_requested():
            now = time.monotonic()
            if wait.republish_due(now, all(v.lockstep.setpoints_received for v in self.vehicles)):
                self.publish_step()   # for followers joining late
            if wait.warn_due(now):
                self.get_logger().warn(f'waiting for {", ".join(behind)} to take odometry of t = '
                                       f'{stamp_ns * 1e-9:.3f} s (lockstep_followers)')
            self._each_step()
            executor.spin_once(timeout_sec=0.05)

    def drain(self, executor):
        """At a stop: the final counts on diagnostics, then wait for the followers to take the last step, so a
        recorder stopped after the simulator holds everything it published (what is still in this process's
        writers is lost when it exits): policy.DrainWatch, or until one left the graph (fly's stop ladder,
        SIGTERM then SIGKILL, bounds it too)."""
        if not rclpy.ok(context=self.context):
            return
        self.publish_diagnostics()
        for call in self.at_final_counts:
            call(executor)
        last = self.vehicles[0].lockstep.last_odom_ns
        watch = policy.DrainWatch(self.acks.acked_ns, time.monotonic())
        while (behind := self.acks.behind(last)) and rclpy.ok(context=self.context):
            gone = [f for f in behind if self.count_publishers(lockstep.ack_topic(f)) == 0]
            if gone or watch.stalled(self.acks.acked_ns, time.monotonic()):
                why = 'left the graph' if gone else f'acknowledged nothing new for {policy.DRAIN_STALL_S} s'
                self.get_logger().warn(f'{", ".join(gone or behind)} {why} before taking the last odometry '
                                       f'(t = {last * 1e-9:.3f} s): the bag may miss the last steps')
                return
            executor.spin_once(timeout_sec=0.05)

    def start_realtime(self):
        self._pacer = policy.RealtimePacer(time.monotonic(), self.sim.time_ns)
        self.hot_timers.append(self.create_timer(1.0 / self.params['odom_rate_hz'], self._realtime_tick,
                                                 clock=self._wall))
        self.publish_step()

    def _realtime_tick(self):
        steps = self._pacer.steps_due(time.monotonic(), self.params['rtf'], self.sim.time_ns, self.sim.step_ns)
        if steps:
            self.advance(steps)
        self.publish_step()


def spin(node, executor):
    """The simulator's loop: lockstep, or realtime paced by its wall-clock tick."""
    if node.params['mode'] == 'lockstep':
        node.run_lockstep(executor)
    else:
        node.start_realtime()
        while node.running():
            executor.spin_once(timeout_sec=0.1)


def main(args=None):
    run_node(NAME, SimNode, refused=(ValueError, SimulationStopped),
             make_executor=lambda node: HotPathExecutor(node.hot_entities),
             spin=spin, args=args, own_signals=True)


if __name__ == '__main__':
    main()
