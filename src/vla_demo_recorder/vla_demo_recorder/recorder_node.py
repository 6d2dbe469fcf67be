"""ROS 2 wrapper of the episode recorder: generic subscriptions, episode services, joystick buttons.

Topics are subscribed as raw CDR bytes (create_subscription(raw=True)) with the type read from the
graph and imported by name, so any message type is recorded without code changes. Like
`ros2 bag record`, the subscription QoS adapts to the publishers (reliable when every publisher is
reliable, else best effort, which also matches sensor-data publishers) with a deep queue, so a
1 kHz topic is not thinned out while the writer thread is busy. Messages are recorded only while an
episode is open; the episode's bag is written by the core Recorder (recorder.py).

Ctrl-C while recording closes the episode as `interrupted`: the writer thread writes what is queued for
up to SHUTDOWN_DRAIN_S (the rest is counted as dropped), then the bag's last chunk and metadata. The
node declares SHUTDOWN_TIMEOUT_S to run_node for that, so its watchdog, meant for a middleware hang,
does not end a bag being closed (it did, with exit code 1, under load: issue 21).
"""
from __future__ import annotations

import importlib
import sys
import time
from collections.abc import Callable

from builtin_interfaces.msg import Time
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sensor_msgs.msg import Joy
from std_srvs.srv import Trigger
from vla_common.catalogue import CatalogueError, load_catalogue
from vla_common.ros.diagnostics import Diagnostics
from vla_common.ros.node_main import ConfigError, run_node
from vla_common.ros.parameters import Param, ParameterTable

from vla_demo_recorder.bag_writer import make_qos, normalize_type
from vla_demo_recorder.lockstep import StampWindow, has_header, header_stamp_ns
from vla_demo_recorder.recorder import Recorder, RecorderError, validate_task
from vla_interfaces.msg import RecorderStatus, StepAnswer
from vla_interfaces.srv import StartEpisode

# controller_node/status: what the controller did with the stick, the assistance's goal and pull among it
DEFAULT_TOPICS = ["joint_states", "camera/image_raw", "camera/camera_info", "detections", "joy",
                  "gripper/status", "controller_node/status"]
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
# s: at Ctrl-C, how long queued messages are still written, and how long closing may take in all
# (the drain, one write or fsync in progress, the last chunk, fsync, metadata). Measured under load 18
# on the 2 cores, recording 640x480 images at 30 Hz: the close took 1.1-3.3 s without a bound.
# SHUTDOWN_TIMEOUT_S + SHUTDOWN_GRACE_S (9 s) stays under the 10 s after which ros2 launch sends SIGKILL.
SHUTDOWN_DRAIN_S = 1.5
SHUTDOWN_TIMEOUT_S = 6.0


# dynamic: applied at once, or (BETWEEN_EPISODES) when idle; the others are read-only (restart)
PARAMETERS = ParameterTable([
    Param("catalogue", "", "YAML file of the object classes and tasks episodes may have ('': the default "
          "catalogue, vla_common/data/catalogue.yaml)", dynamic=True),
    Param("output_dir", "~/vla_demos", "folder that receives one bag folder per episode", dynamic=True),
    Param("topics", DEFAULT_TOPICS, "topics to record (relative names resolve in the node's namespace)",
          array="string_array"),
    Param("image_every_n", 1, "record every n-th image (1 = all; the paper needs only the first frame "
          "of an episode)", range=(1, 10000), dynamic=True),
    Param("flush_period_s", 0.5, "complete MCAP chunks are flushed and fsynced at least this often",
          range=(0.05, 1.0), dynamic=True),
    Param("fsync", True, "fsync at every flush (crash safety against power loss)", dynamic=True),
    Param("qos_depth", 1000, "subscription queue depth (messages)", range=(1, 100000)),
    Param("max_queue_mb", 1024, "writer queue bound; beyond it messages are counted as dropped",
          range=(16, 65536), dynamic=True),
    Param("delete_discarded", False, "delete discarded episodes instead of keeping them marked 'discarded'",
          dynamic=True),
    Param("topic_poll_period_s", 0.5, "how often to look for publishers of unsubscribed topics",
          range=(0.05, 10.0), dynamic=True),
    Param("status_period_s", 0.5, "period of ~/status (wall s, also while a simulation holds)",
          range=(0.02, 10.0), dynamic=True),
    Param("joy_topic", "joy", "sensor_msgs/Joy topic carrying the episode buttons"),
    Param("joy_task", "", "task of episodes started with the joystick (e.g. bread/push_east); "
          "checked against the catalogue", dynamic=True),
    Param("start_button", 0, "joystick button that starts an episode (-1: none)", range=(-1, 127),
          dynamic=True),
    Param("stop_button", 1, "joystick button that stops and keeps the episode (-1: none)", range=(-1, 127),
          dynamic=True),
    Param("discard_button", 2, "joystick button that stops and discards the episode (-1: none)",
          range=(-1, 127), dynamic=True),
    Param("button_debounce_s", 0.5, "ignore repeated presses within this time", range=(0.0, 5.0),
          dynamic=True),
    Param("lockstep", False, "a participant of the simulated Panda's lockstep (vla_evaluation generate): "
          "answer every joint state once handled (lockstep/answer), and leave out a message stamped at or "
          "before the episode's start: an episode then holds the same steps at any load"),
])
LOCKSTEP_QOS = QoSProfile(depth=100)  # reliable: in lockstep a lost answer is a hang
# They shape an episode's bag: a change while recording is refused.
BETWEEN_EPISODES = ("output_dir", "flush_period_s", "fsync")


def import_message(msgtype: str) -> type:
    """`pkg/msg/Type` -> the generated Python class (ImportError/AttributeError when absent)."""
    pkg, sub, name = normalize_type(msgtype).split("/")
    return getattr(importlib.import_module(f"{pkg}.{sub}"), name)


def _policy_name(policy) -> str:
    return policy.name.lower() if hasattr(policy, "name") else "unknown"


class RecorderNode(Node):
    """Records the configured topics into one rosbag2 MCAP bag per episode."""

    shutdown_timeout_s = SHUTDOWN_TIMEOUT_S  # read by run_node: on_shutdown closes a bag

    def __init__(self, **kwargs) -> None:
        super().__init__("recorder", **kwargs)
        p = PARAMETERS.declare(self, self._on_parameter)
        try:
            catalogue = load_catalogue(p["catalogue"])
        except CatalogueError as err:
            raise ConfigError(f"parameter 'catalogue': {err}") from err
        try:
            joy_task = validate_task(p["joy_task"], catalogue) if p["joy_task"] else ""
        except RecorderError as err:
            raise ConfigError(f"parameter 'joy_task': {err}") from err
        self.topics = list(p["topics"])
        self.lockstep, self.window = p["lockstep"], StampWindow()
        self._newest: dict[str, int] = {}   # lockstep: per stamped topic, the newest stamp recorded (ns)
        if self.lockstep and self._resolved("joint_states") not in {self._resolved(t) for t in self.topics}:
            raise ConfigError("parameter 'lockstep': the recorder answers the joint states it records; "
                              "'topics' must hold joint_states")
        self.answer_pub = (self.create_publisher(StepAnswer, "lockstep/answer", LOCKSTEP_QOS)
                           if self.lockstep else None)
        self.image_every_n = p["image_every_n"]
        self.qos_depth = p["qos_depth"]
        self.joy_topic = p["joy_topic"]
        self.joy_task = joy_task
        self.buttons = {"start": p["start_button"], "stop": p["stop_button"], "discard": p["discard_button"]}
        self.debounce_s = p["button_debounce_s"]
        output_dir, flush, fsync = p["output_dir"], p["flush_period_s"], p["fsync"]
        max_queue_mb, delete_discarded = p["max_queue_mb"], p["delete_discarded"]
        poll, status_period = p["topic_poll_period_s"], p["status_period_s"]

        self.recorder = Recorder(output_dir, flush_period_s=flush, fsync=fsync,
                                 max_queue_bytes=max_queue_mb << 20, delete_discarded=delete_discarded,
                                 catalogue=catalogue, log=self._log)
        self._subs: dict[str, tuple[str, list, object]] = {}  # topic -> (type, offered qos, sub)
        self._image_counts: dict[str, int] = {}
        self._warned: set[str] = set()
        self._prev_buttons: list[int] = []
        self._last_press: dict[str, float] = {}

        self.create_service(StartEpisode, "~/start_episode", self._on_start)
        self.create_service(Trigger, "~/stop_episode", lambda req, res: self._on_stop(res, keep=True))
        self.create_service(Trigger, "~/discard_episode", lambda req, res: self._on_stop(res, keep=False))
        self.status_pub = self.create_publisher(RecorderStatus, "~/status", 10)
        self.diagnostics = Diagnostics(self)
        self.create_subscription(Joy, self.joy_topic, self._on_joy, qos_profile_sensor_data)
        # discovery is a wall-clock matter: on /clock a held simulation (lockstep) would never let the
        # recorder find joint_states, whose first state it must answer
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._poll_timer = self.create_timer(poll, self._poll_topics, clock=steady)
        # the status too: it says how far the recorder's clock has come, which an orchestrator waits for
        # while the simulation holds (on /clock no status came then, and a wait hung when the last one
        # fell before the hold: the study's "recorder's clock to pass the reset", at load)
        self._status_timer = self.create_timer(status_period, self._publish_status, clock=steady)
        self._apply = self._appliers()
        self._poll_topics()
        if problem := self.recorder.check_output_dir():
            self.get_logger().error(f"{problem}; episodes cannot start until this is fixed")
        self.get_logger().info(f"recording {', '.join(self._resolved(t) for t in self.topics)} into "
                               f"{self.recorder.output_dir} (idle; call ~/start_episode)")

    def _on_parameter(self, name: str, value) -> str | None:
        """Apply a run-time change of a dynamic parameter, or return why it is refused."""
        if name in BETWEEN_EPISODES and self.recorder.recording:
            return (f"{name} changes between episodes; stop or discard episode "
                    f"{self.recorder.state().episode_index} first")
        try:
            if name == "output_dir":
                self.recorder.set_output_dir(value)
            elif name == "catalogue":
                self._set_catalogue(value)
            elif name == "joy_task":
                self.joy_task = validate_task(value, self.recorder.catalogue) if value else ""
            else:
                self._apply[name](value)
        except (RecorderError, CatalogueError) as err:
            return str(err)
        return None

    def _set_catalogue(self, path: str) -> None:
        """Tasks of the next episodes come from `path`; refused when joy_task is not one of them."""
        catalogue = load_catalogue(path)
        if self.joy_task:
            try:
                validate_task(self.joy_task, catalogue)
            except RecorderError as err:
                raise RecorderError(f"joy_task {self.joy_task!r} is not a task of {path!r} ({err}); "
                                    "change joy_task first") from err
        self.recorder.catalogue = catalogue

    def _appliers(self) -> dict[str, Callable[[object], None]]:
        """How each dynamic parameter other than output_dir, catalogue and joy_task takes effect."""
        rec, buttons = self.recorder, self.buttons

        def period(timer):
            return lambda v: setattr(timer, "timer_period_ns", int(v * 1e9))

        return {
            "image_every_n": lambda v: setattr(self, "image_every_n", int(v)),
            "flush_period_s": lambda v: setattr(rec, "flush_period_s", float(v)),
            "fsync": lambda v: setattr(rec, "fsync", bool(v)),
            "max_queue_mb": lambda v: setattr(rec, "max_queue_bytes", int(v) << 20),
            "delete_discarded": lambda v: setattr(rec, "delete_discarded", bool(v)),
            "topic_poll_period_s": period(self._poll_timer),
            "status_period_s": period(self._status_timer),
            "start_button": lambda v: buttons.__setitem__("start", int(v)),
            "stop_button": lambda v: buttons.__setitem__("stop", int(v)),
            "discard_button": lambda v: buttons.__setitem__("discard", int(v)),
            "button_debounce_s": lambda v: setattr(self, "debounce_s", float(v)),
        }

    def _log(self, level: str, text: str) -> None:
        {"error": self.get_logger().error, "warn": self.get_logger().warning}.get(
            level, self.get_logger().info)(text)

    def _resolved(self, topic: str) -> str:
        return self.resolve_topic_name(topic)

    # -- subscriptions -------------------------------------------------------------------------
    def subscribed_topics(self) -> list[str]:
        """Topics subscribed so far (a configured topic is subscribed once it has a publisher)."""
        return sorted(self._subs)

    def _offered_qos(self, topic: str) -> tuple[list, QoSProfile] | None:
        infos = self.get_publishers_info_by_topic(topic)
        if not infos:
            return None
        offered = [make_qos(_policy_name(i.qos_profile.reliability), _policy_name(i.qos_profile.durability),
                            i.qos_profile.depth, _policy_name(i.qos_profile.history)) for i in infos]
        reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=self.qos_depth,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
        return offered, qos

    def _poll_topics(self) -> None:
        """Subscribe to configured topics as soon as a publisher (and so the type) is known."""
        wanted = {self._resolved(t) for t in self.topics} - set(self._subs)
        if not wanted:
            return
        types = dict(self.get_topic_names_and_types())
        for topic in sorted(wanted & set(types)):
            found = self._offered_qos(topic)
            if found is None:
                continue
            offered, qos = found
            msgtype = normalize_type(types[topic][0])
            try:
                cls = import_message(msgtype)
            except (ImportError, AttributeError) as err:
                if topic not in self._warned:
                    self._warned.add(topic)
                    self.get_logger().warning(f"cannot record {topic}: type {msgtype} not importable ({err})")
                continue
            callback = self._make_callback(topic, msgtype, stamped=self.lockstep and has_header(cls),
                                           answers=self.lockstep and topic == self._resolved("joint_states"))
            sub = self.create_subscription(cls, topic, callback, qos, raw=True)
            self._subs[topic] = (msgtype, offered, sub)
            self.get_logger().info(f"subscribed to {topic} [{msgtype}], "
                                   f"{qos.reliability.name.lower()}, depth {qos.depth}")

    def _make_callback(self, topic: str, msgtype: str, stamped: bool = False, answers: bool = False):
        """The topic's raw callback. Lockstep: a `stamped` message is kept only when stamped after the
        episode's start; the joint states (`answers`) are answered once recorded."""
        is_image = msgtype in IMAGE_TYPES
        clock = self.get_clock()

        def record(data: bytes) -> None:
            if not self.recorder.recording or (stamped and not self.window.keeps(data)):
                return
            if is_image:
                n = self._image_counts.get(topic, 0)
                self._image_counts[topic] = n + 1
                if n % self.image_every_n:
                    return
            if self.recorder.record(topic, msgtype, self._subs[topic][1], clock.now().nanoseconds, data) \
                    and stamped:
                self._newest[topic] = max(self._newest.get(topic, 0), header_stamp_ns(data))

        def callback(data: bytes) -> None:
            record(data)
            if answers:
                self._answer(header_stamp_ns(data))
        return callback

    def _answer(self, stamp_ns: int) -> None:
        """Lockstep: the joint state stamped `stamp_ns` is handled (recorded while an episode is open)."""
        msg = StepAnswer(node=self.get_name())
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self.answer_pub.publish(msg)

    # -- episodes ------------------------------------------------------------------------------
    def start_episode(self, task: str, note: str = "") -> tuple[bool, str, str]:
        topics = {t: (mt, offered) for t, (mt, offered, _s) in self._subs.items()}
        self._image_counts.clear()
        self._newest.clear()
        try:
            start_ns = self.get_clock().now().nanoseconds
            if self.lockstep:
                self.window.open(start_ns)
            path = self.recorder.start(task, note, topics, start_time_ns=start_ns)
        except RecorderError as err:
            self.get_logger().error(f"start_episode: {err}")
            return False, str(err), ""
        st = self.recorder.state()
        message = f"recording episode {st.episode_index} ({st.task}) to {path}"
        self.get_logger().info(message)
        return True, message, str(path)

    def stop_episode(self, keep: bool) -> tuple[bool, str]:
        try:
            result = self.recorder.stop(keep=keep, end_time_ns=self.get_clock().now().nanoseconds)
        except RecorderError as err:
            self.get_logger().error(f"{'stop' if keep else 'discard'}_episode: {err}")
            return False, str(err)
        message = result.summary()
        (self.get_logger().info if result.outcome != "failed" else self.get_logger().error)(message)
        return result.outcome in ("kept", "discarded"), message

    def _guarded(self, what: str, action: Callable[[], tuple]) -> tuple:
        """Run an episode action; an unexpected error is logged, shown in ~/status and returned as
        (False, reason): no request or button press can take the node down."""
        try:
            return action()
        except Exception as err:  # reported to the caller instead of killing the node
            message = f"{what} failed: {type(err).__name__}: {err}"
            self.get_logger().error(message)
            self.recorder.report_error(message)
            return False, message

    def _on_start(self, request: StartEpisode.Request, response: StartEpisode.Response):
        result = self._guarded("start_episode", lambda: self.start_episode(request.task, request.note))
        response.success, response.message = result[0], result[1]
        response.bag_path = result[2] if len(result) > 2 else ""
        return response

    def _on_stop(self, response: Trigger.Response, keep: bool):
        what = "stop_episode" if keep else "discard_episode"
        response.success, response.message = self._guarded(what, lambda: self.stop_episode(keep))
        return response

    def _on_joy(self, msg: Joy) -> None:
        """Rising edges of the configured buttons start/stop/discard episodes (hands-free demos)."""
        buttons = list(msg.buttons)
        prev = self._prev_buttons + [0] * max(0, len(buttons) - len(self._prev_buttons))
        self._prev_buttons = buttons
        now = time.monotonic()
        for action, index in self.buttons.items():
            if index < 0 or index >= len(buttons) or not (buttons[index] and not prev[index]):
                continue
            if now - self._last_press.get(action, -1e9) < self.debounce_s:
                continue
            self._last_press[action] = now
            recording = self.recorder.recording
            if action == "start" and not recording:
                if not self.joy_task:
                    self.get_logger().error("start button pressed but parameter joy_task is empty")
                    continue
                self._guarded("start button", lambda: self.start_episode(self.joy_task,
                                                                         note="started with the joystick"))
            elif action in ("stop", "discard") and recording:
                self._guarded(f"{action} button", lambda keep=action == "stop": self.stop_episode(keep))

    # -- status --------------------------------------------------------------------------------
    def _publish_status(self) -> None:
        st = self.recorder.state()
        msg = RecorderStatus()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.recording, msg.task, msg.bag_path = st.recording, st.task, st.bag_path
        msg.episode_index = st.episode_index
        msg.messages_written, msg.bytes_written = st.messages_written, st.bytes_written
        msg.messages_dropped, msg.last_error = st.messages_dropped, st.last_error
        newest = dict(self._newest)   # a copy: the callbacks may add to it meanwhile
        msg.stamped_topics = list(newest)
        msg.newest_stamps = [Time(sec=ns // 10**9, nanosec=ns % 10**9) for ns in newest.values()]
        self.status_pub.publish(msg)
        self.diagnostics.update("error" if st.last_error else "ok", st.last_error or (
            f"recording {st.task}" if st.recording else "idle"), episode_index=st.episode_index,
            messages_written=st.messages_written, messages_dropped=st.messages_dropped)

    def on_shutdown(self) -> None:
        """Close a running episode (outcome `interrupted`) while the logger still works."""
        result = self.recorder.shutdown(drain_s=SHUTDOWN_DRAIN_S)
        if result is not None:
            self.get_logger().warning(f"shut down while recording: {result.summary()}")

    def destroy_node(self) -> None:
        self.on_shutdown()  # again for callers that destroy the node without run_node (idempotent)
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return run_node(RecorderNode, "recorder", args)


if __name__ == "__main__":
    sys.exit(main())
