"""operator_station: the thin ROS wrapper around the station's server (:mod:`.server`) and link rules
(:mod:`.link`). It publishes sensor_msgs/Joy stamped here on arrival, relays the nodes' status to the
pages in words, turns the pages' requests into the nodes' own services, and serves the questionnaire
action (``~/questionnaire``: the page shows it, the driving page answers it)."""
from __future__ import annotations

import gc
import secrets
import sys
import threading
import time
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.srv import GetParameters, SetParametersAtomically
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image, Joy
from std_srvs.srv import SetBool, Trigger
from vla_common.ros.node_main import ConfigError, run_node
from vla_common.ros.parameters import THREAD_PRIORITY, Param, ParameterTable
from vla_common.ros.qos import SENSOR_QOS, image_qos

from vla_interfaces.action import Questionnaire as QuestionnaireAction
from vla_interfaces.msg import ControllerStatus, DetectionArray, GripperStatus, RecorderStatus, SafetyStatus
from vla_interfaces.srv import GripperCommand, SelectTarget, StartEpisode
from vla_operator import settings as cfg
from vla_operator.access import TokenError, load_token
from vla_operator.frames import FrameEncoder, image_problem
from vla_operator.link import LinkParams
from vla_operator.questionnaire import Questionnaire, goal_refusal
from vla_operator.server import Station
from vla_operator.view import CHECK_PERIOD_S, ViewWatch
from vla_operator.words import controller_words, safety_words

NODE_NAME = "operator_station"
DEFAULT_TOKEN_FILE = Path("~/.config/vla_operator/token")
TEXT_CHARS = 300      # a status text shown to the person: longer ones are cut
MAX_BOXES = 32        # detections drawn and offered on the page (a detector gives a handful)
# Only the newest frame kept (reliable, as the camera): a station that fell behind shows the latest
# frame and never works through a backlog (IMAGE_QOS keeps 30, for the detector and the recorder).
LATEST_IMAGE_QOS = image_qos(depth=1)
# The end-effector baseline's mode button, pressed from the page: held in the Joy this long, as a finger
# on a joystick button (the controller acts on the press's rising edge, debounced by its ee_debounce)
MODE_PRESS_S = 0.1

PARAMETERS = ParameterTable([
    THREAD_PRIORITY,   # on the operator's path: SCHED_FIFO where allowed (vla_common.priority)
    Param("bind", "127.0.0.1", "address the page is served on (0.0.0.0: every interface)"),
    Param("port", 8080, "TCP port; 0: any free port (the address is logged)", range=(0, 65535)),
    Param("token_file", "", "file holding the token every page's address carries (on loopback too), "
          "made with a new random token when missing; empty: ~/.config/vla_operator/token"),
    Param("hosts", "", "other names of this station that a page's address may use, comma-separated "
          "(e.g. robot-pc.local); its addresses and localhost always work"),
    Param("rate", 50.0, "Hz: Joy republished at this rate while a page drives (the controller's "
          "joy_timeout is the second line)", range=(20.0, 200.0)),
    Param("stale_after", 0.15, "s: input older than this is dropped, a held one expires",
          range=(0.02, 1.0)),
    Param("heartbeat_timeout", 0.5, "s without a message from the driving page: zero", range=(0.1, 5.0)),
    Param("speed_scale", 1.0, "caregiver's speed scale: the page's axis times this", range=(0.05, 1.0),
          dynamic=True),
    Param("settings_file", "", "caregiver settings (JSON) kept on this PC; empty: "
          "~/.config/vla_operator/settings.json"),
    Param("jpeg_quality", 80, "JPEG quality of the live view", range=(30, 95)),
    Param("tasks", ["bread/push_east", "soda_can/pick_place", "milk_carton/pour", "cereal_box/push_east",
                    "glass_bottle/pick_place"], "tasks offered on the page (the recorder checks them)"),
    Param("bridge", "panda_bridge", "the bridge's node name (its ~/estop, ~/gripper, ~/status)"),
    Param("controller", "controller_node", "the controller's node name"),
    Param("recorder", "recorder", "the recorder's node name"),
])


def address_banner(address: str) -> str:
    """The lines that give the person the page's address, once, set apart from the nodes' log, with
    what to expect: the rest of the graph may still be starting (the page says so until it answers)."""
    rule = "[operator_station] " + "-" * 72
    return "\n".join((
        rule,
        f"[operator_station] the operator station is at {address}",
        "[operator_station] open it in a browser. The rest of the graph may take a minute to start:",
        "[operator_station] wait until the page no longer says \"Starting\", then drive.",
        rule))


class StationNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.p = p = PARAMETERS.declare(self, on_change=self._on_change)
        token = self._token()
        self.settings_path = Path(p["settings_file"] or Path.home() / ".config/vla_operator/settings.json")
        self._settings_lock = threading.Lock()   # pages' requests and service answers come from 2 threads
        self.settings, self.settings_problem = cfg.load(
            self.settings_path, {**cfg.defaults(), "speed_scale": p["speed_scale"]})
        if self.settings_problem:
            self.get_logger().error(self.settings_problem)
        if self.settings["speed_scale"] != p["speed_scale"]:   # the caregiver's file wins
            self.set_parameters([Parameter("speed_scale", value=self.settings["speed_scale"])])
        self.joy_pub = self.create_publisher(Joy, "joy", 10)
        self.status_pub = self.create_publisher(DiagnosticStatus, "~/status", 10)
        self.state: dict = {"tasks": list(p["tasks"]), "settings": self.settings,
                            "settings_problem": self.settings_problem, "questionnaire": None,
                            "motion_held": ""}
        self._connect_nodes(p["bridge"], p["controller"], p["recorder"])
        self._controller_timer = self.create_timer(1.0, self._sync_controller)
        self._ee_button = -1          # the controller's ee_mode_button, read once it is up
        self._mode_until = -1.0       # monotonic s: the mode button is held in the Joy until then
        self._dets: dict = {"boxes": [], "size": [0, 0]}
        self.view = ViewWatch()       # is the live view live: view_stale and view_age_s in the state
        self.station = Station(
            Path(get_package_share_directory("vla_operator")) / "web", p["bind"], p["port"], token,
            self._publish_axis, self._request,
            LinkParams(stale_after=p["stale_after"], heartbeat_timeout=p["heartbeat_timeout"]),
            names=tuple(n.strip() for n in p["hosts"].split(",") if n.strip()),
        )
        self.address = self.station.start()
        self._state()   # the settings (key map) even before any node's status
        self.frames = FrameEncoder(self._frame_out, p["jpeg_quality"])
        self.create_timer(CHECK_PERIOD_S, self._watch_view)
        self._init_questionnaire()
        self.create_timer(1.0 / p["rate"], self._tick)
        self.create_timer(1.0, self._publish_status)
        # Everything built so far (modules, rclpy, pydantic, OpenCV) lives as long as the node: frozen
        # out of the garbage collector, a full collection scans only what came since. Under a page's
        # flood of junk, full collections of the whole heap took 58-114 ms each and held back another
        # page's e-stop by as much (issue 32).
        gc.freeze()
        # printed once, not logged: the person who starts the graph finds it among the nodes' lines
        print(address_banner(self.address), flush=True)

    def _connect_nodes(self, b: str, c: str, r: str) -> None:
        """The other nodes' status (subscriptions) and services (clients): bridge, controller, recorder."""
        self.create_subscription(Image, "camera/image_raw", self._on_image, LATEST_IMAGE_QOS)
        self.create_subscription(DetectionArray, "detections", self._on_dets, SENSOR_QOS)
        self.create_subscription(ControllerStatus, f"{c}/status", self._on_ctrl, 10)
        self.create_subscription(SafetyStatus, f"{b}/status", self._on_safety, 10)
        self.create_subscription(GripperStatus, "gripper/status", self._on_gripper, 10)
        self.create_subscription(RecorderStatus, f"{r}/status", self._on_recorder, 10)
        self.clients_ = {
            "estop": self.create_client(SetBool, f"{b}/estop"),
            "teaching": self.create_client(SetBool, f"{b}/set_teaching"),
            "gripper": self.create_client(GripperCommand, f"{b}/gripper"),
            "select": self.create_client(SelectTarget, f"{c}/select_target"),
            "redetect": self.create_client(Trigger, f"{c}/redetect"),
            "start": self.create_client(StartEpisode, f"{r}/start_episode"),
            "stop": self.create_client(Trigger, f"{r}/stop_episode"),
            "discard": self.create_client(Trigger, f"{r}/discard_episode"),
        }
        self.ctrl_set = self.create_client(SetParametersAtomically, f"{c}/set_parameters_atomically")
        self.ctrl_get = self.create_client(GetParameters, f"{c}/get_parameters")

    def _token(self) -> str:
        """The token every page and socket must carry, loopback included (see access.py): token_file's,
        or one made there at the first start; without a token_file the default file, or, where that
        cannot be written, a new one for this run."""
        path = Path(self.p["token_file"] or DEFAULT_TOKEN_FILE.expanduser())
        try:
            token, made = load_token(path)
        except TokenError as e:
            if self.p["token_file"]:
                raise ConfigError(str(e)) from None
            self.get_logger().warning(f"{e}: a new token for this run only")
            return secrets.token_urlsafe(24)
        if made:
            self.get_logger().info(f"a new token for the station's address was written to {path}")
        return token

    # ------------------------------------------------------------------ input
    def _publish_axis(self, axis: float) -> None:
        """Stamped by this node on arrival (the browser's clock is not trusted)."""
        msg = Joy()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = ""  # a Joy has no geometry: no TF frame (test_frames)
        msg.axes = [float(axis) * float(self.settings.get("speed_scale", 1.0)), 0.0]
        buttons = [0] * max(4, self._ee_button + 1)
        if self._ee_button >= 0 and time.monotonic() < self._mode_until:
            buttons[self._ee_button] = 1
        msg.buttons = buttons
        self.joy_pub.publish(msg)

    def _press_mode_button(self, reply) -> None:
        """The page's "next axis": the controller's own mode button, pressed in the Joy (so the
        controller's rule and debounce apply, as to a joystick's press)."""
        if self._ee_button < 0:
            reply({"what": "next axis", "ok": False, "message":
                   f"{self.p['controller']} has no end-effector mode button (ee_mode_button is -1, or it "
                   "has not answered yet)"})
            return
        with self.station.lock:
            now = time.monotonic()
            self._mode_until = now + MODE_PRESS_S
            self._publish_axis(self.station.link.value(now))
        reply({"what": "next axis", "ok": True, "message": "the mode button was pressed"})

    def _tick(self) -> None:
        self._q_finish()
        now = time.monotonic()
        with self.station.lock:   # read and published together: a release's zero is never followed by
            went_silent = self.station.link.tick(now)      # the held value read just before it
            if self.station.link.driver() is not None or went_silent:
                self._publish_axis(self.station.link.value(now))

    # ------------------------------------------------------------------ requests from a page
    def _request(self, msg: dict, reply) -> None:
        kind = msg["type"]
        if kind in ("estop", "release_estop"):
            self._call("estop", SetBool.Request(data=kind == "estop"), kind, reply)
        elif kind == "teaching":
            self._call("teaching", SetBool.Request(data=msg["on"]), kind, reply)
        elif kind == "gripper":
            self._call("gripper", GripperCommand.Request(command=GripperCommand.Request.TOGGLE), kind, reply)
        elif kind == "ee_next":
            self._press_mode_button(reply)
        elif kind == "select":
            req = SelectTarget.Request(by=msg["by"], class_id=str(msg.get("class_id", "")),
                                       index=int(msg.get("index", -1)), x=float(msg.get("x", 0.0)),
                                       y=float(msg.get("y", 0.0)))
            self._call("select", req, kind, reply)
        elif kind == "redetect":
            self._call("redetect", Trigger.Request(), kind, reply)
        elif kind == "episode":
            action = msg["action"]
            req = StartEpisode.Request(task=msg["task"]) if action == "start" else Trigger.Request()
            self._call(action, req, f"episode {action}", reply)
        elif kind == "settings":
            self._apply_settings(msg["values"], reply)
        elif kind == "answers":
            self._answered(msg, reply)

    def _call(self, name: str, req, what: str, reply) -> None:
        client = self.clients_[name]
        if not client.service_is_ready():
            reply({"what": what, "ok": False, "message": f"{client.srv_name} is not available"})
            return
        future = client.call_async(req)
        future.add_done_callback(lambda f: reply(
            {"what": what, "ok": bool(f.result().success), "message": f.result().message}
            if f.exception() is None else {"what": what, "ok": False, "message": str(f.exception())}))

    # ------------------------------------------------------------------ caregiver settings
    def _sync_controller(self) -> None:
        """Once the controller is up: give it the saved deadband and assistance level, or show the ones
        it has; and learn which button is its end-effector mode button (the page's "next axis")."""
        if not (self.ctrl_set.service_is_ready() and self.ctrl_get.service_is_ready()):
            return
        self._controller_timer.cancel()

        def button(f) -> None:
            values = f.result().values if f.exception() is None else []
            if values and values[0].type == Parameter.Type.INTEGER.value:
                self._ee_button = int(values[0].integer_value)
        self.ctrl_get.call_async(GetParameters.Request(names=["ee_mode_button"])).add_done_callback(button)
        saved = {n: self.settings[n] for n in cfg.CONTROLLER_SETTINGS if self.settings[n] is not None}
        if saved:
            self._set_controller(saved, lambda ok, why: None if ok else self._problem(
                f"{self.p['controller']} refused {_named(saved)} saved here: {why}"))
        unknown = [n for n in cfg.CONTROLLER_SETTINGS if n not in saved]
        if not unknown:
            return

        def got(f) -> None:
            values = f.result().values if f.exception() is None else []
            have = {}
            for name, v in zip(unknown, values, strict=False):
                try:   # the controller's value, as any other, is shown only when it is a valid setting
                    have.update(cfg.validate({name: _value(v)}))
                except cfg.SettingError:
                    pass
            have = {n: v for n, v in have.items() if v is not None}
            if have:
                with self._settings_lock:
                    self.settings = {**self.settings, **have}
                self._state(settings=self.settings)
        self.ctrl_get.call_async(GetParameters.Request(names=unknown)).add_done_callback(got)

    def _problem(self, text: str) -> None:
        self.get_logger().error(text)
        self._state(settings_problem=text)

    def _set_controller(self, values: dict, done) -> None:
        """The controller's own parameters, all or none (its set_parameters_atomically service):
        done(ok, its reason)."""
        if not self.ctrl_set.service_is_ready():
            done(False, f"{self.ctrl_set.srv_name} is not available (is {self.p['controller']} running?)")
            return
        req = SetParametersAtomically.Request(parameters=[
            Parameter(n, value=float(v) if n == "deadband" else v).to_parameter_msg()
            for n, v in values.items()])

        def answered(f) -> None:
            if f.exception() is not None:
                done(False, str(f.exception()))
            else:
                r = f.result().result
                done(bool(r.successful), r.reason)
        self.ctrl_set.call_async(req).add_done_callback(answered)

    def _apply_settings(self, values: dict, reply) -> None:
        """Validate everything first (the page is untrusted), then the controller's deadband and
        assistance level (refused with its reason: nothing else changes), then this node's values, then
        the file."""
        def refuse(why: str) -> None:
            reply({"what": "settings", "ok": False, "message": why})
        try:
            clean = cfg.validate(values)
        except cfg.SettingError as e:
            refuse(str(e))
            return
        for name in cfg.CONTROLLER_SETTINGS:
            if clean.get(name, 0) is None:
                clean.pop(name)   # none: leave the controller's as it is
        changed = {n: clean[n] for n in cfg.CONTROLLER_SETTINGS
                   if n in clean and clean[n] != self.settings[n]}
        if not changed:
            self._commit(clean, reply)
            return

        def answered(ok: bool, why: str) -> None:
            if ok:
                self._commit(clean, reply)
            else:
                refuse(f"{self.p['controller']} refused {_named(changed)}: {why}")
        self._set_controller(changed, answered)

    def _commit(self, clean: dict, reply) -> None:
        with self._settings_lock:
            new = {**self.settings, **clean}
            if new["speed_scale"] != self.p["speed_scale"]:
                result = self.set_parameters([Parameter("speed_scale", value=new["speed_scale"])])[0]
                if not result.successful:
                    reply({"what": "settings", "ok": False, "message": result.reason})
                    return
            self.settings = new
            message = "saved on the robot PC"
            try:
                if self.settings_problem:   # the refused file is kept, not overwritten
                    aside = cfg.keep_aside(self.settings_path)
                    if aside is not None:
                        message += f" (the file that was refused is kept as {aside.name})"
                cfg.save(self.settings_path, new)
                self.settings_problem = ""
            except OSError as e:
                message = f"applied but not saved: {e.strerror}"
        self._state(settings=self.settings, settings_problem=self.settings_problem)
        reply({"what": "settings", "ok": not message.startswith("applied but"), "message": message})

    def _on_change(self, name, value):
        if name == "speed_scale":
            self.p["speed_scale"] = float(value)
            self.settings = {**self.settings, "speed_scale": float(value)}
        return None

    # ------------------------------------------------------------------ what the pages see
    def _state(self, **kw) -> None:
        self.state.update(kw, **self.view.fields())
        self.station.set_state(self.state)

    def _watch_view(self) -> None:
        """The pages are told at once when the view goes stale or comes back (and, while stale, how old
        it is, every second). With the caregiver's stop_on_stale_view, a stale view holds all motion:
        zero at once, motion refused while it lasts, and a neutral input first once the view is back
        (the link's hold, a stop as any other: the arming rule)."""
        changed = self.view.changed()
        stale = self.view.fields()["view_stale"]
        with self.station.lock:
            link = self.station.link
            was = link.held
            if stale and self.settings["stop_on_stale_view"]:
                if link.hold("the live view stopped (no new picture for 1 s): let go, and move when the "
                             "view is back"):
                    self._publish_axis(0.0)
            elif link.held:
                link.release_hold()
            held = link.held
        if changed is not None or held != was:
            self._state(motion_held=held)

    def _frame_out(self, jpeg: bytes, meta: dict) -> None:
        """From the encoder's thread: the pages' next frame; the view is live."""
        self.station.set_frame(jpeg, meta)
        self.view.seen()

    def _on_image(self, msg: Image) -> None:
        """Any peer may publish here: the encoder checks the image and counts what it cannot show."""
        if not self.station.wants_frames():   # nobody to show it to; a showable image: the camera lives
            if image_problem(msg.width, msg.height, msg.encoding, msg.step, len(msg.data)) is None:
                self.view.seen()
            return
        self.frames.submit(msg.data, msg.width, msg.height, msg.encoding,
                           {"width": msg.width, "height": msg.height, **self._dets}, step=msg.step)

    def _on_dets(self, msg: DetectionArray) -> None:
        """The boxes drawn over the view and offered as targets: the first MAX_BOXES of a peer's message
        (it goes with every frame to every page), class names cut, numbers as they are (the server
        sends a NaN as null)."""
        self._dets = {"size": [msg.image_width, msg.image_height], "boxes": [
            {"class_id": d.class_id[:64], "score": d.score, "cx": d.center_x, "cy": d.center_y,
             "w": d.size_x, "h": d.size_y} for d in msg.detections[:MAX_BOXES]]}

    # Any DDS peer may publish these: their texts are cut to TEXT_CHARS (a person reads a sentence, not
    # 60 KB; issue 32's peer sent 60 KB texts at 350 Hz), and the pages get only the newest state.
    def _on_ctrl(self, m: ControllerStatus) -> None:
        code = int(m.code)
        self._state(controller={"code": code, "words": controller_words(code), "reason": _cut(m.reason),
                                "mode": _cut(m.mode), "ee_axis": _cut(m.ee_axis),
                                "latched_class": _cut(m.latched_class), "latched_by": _cut(m.latched_by),
                                "latched_x": m.latched_x, "latched_y": m.latched_y,
                                # the assistance: its level and the goal it infers (NaN: none; sent as null)
                                "assistance": _cut(m.assistance), "goal_task": _cut(m.goal_task),
                                "goal_confidence": m.goal_confidence, "goal_share": m.goal_share,
                                "goal_stage": _cut(m.goal_stage), "goal_image_x": m.goal_image_x,
                                "goal_image_y": m.goal_image_y})

    def _on_safety(self, m: SafetyStatus) -> None:
        self._state(safety={"code": int(m.code), "words": safety_words(int(m.code)), "text": _cut(m.text),
                            "estop": bool(m.estop_active), "teaching": int(m.code) == SafetyStatus.TEACHING,
                            "gripper": _cut(m.gripper)})

    def _on_gripper(self, m: GripperStatus) -> None:
        self._state(gripper={"text": _cut(m.text), "holding": _cut(m.holding)})

    def _on_recorder(self, m: RecorderStatus) -> None:
        self._state(recorder={"recording": bool(m.recording), "task": _cut(m.task),
                              "episode": int(m.episode_index), "error": _cut(m.last_error)})

    # ------------------------------------------------------------------ the questionnaire (an action)
    # A person takes minutes to answer: an action, not a service (the client waits without blocking
    # this node, may cancel, and is told whether a page can answer). One waits at a time. Its goal
    # handle is finished on the executor: answers (from the server's thread) and cancels are handed
    # over to the node's Joy timer (`rate` Hz; rclpy's EventsExecutor has no guard conditions), and
    # the goal is executed only then, with the outcome ready.
    def _init_questionnaire(self) -> None:
        self._q_lock = threading.Lock()
        self._q_waiting = None           # (goal handle, Questionnaire) shown on the pages
        self._q_outcomes: dict = {}      # goal id -> (kind, answers, message): to finish on the executor
        self._q_ready: list = []         # goal handles whose outcome is ready
        self._q_seen = None              # (pages, driver) in the last feedback
        self._q_next = 0
        self.q_server = ActionServer(
            self, QuestionnaireAction, "~/questionnaire", execute_callback=self._q_execute,
            goal_callback=self._q_goal, handle_accepted_callback=self._q_accepted,
            cancel_callback=self._q_cancel)

    def _q_goal(self, goal) -> GoalResponse:
        why = goal_refusal(goal.title, goal.statements, goal.scale_min, goal.scale_max, goal.min_label,
                           goal.max_label, self.station.link.params.max_message_bytes)
        if why:
            self.get_logger().error(f"questionnaire refused: {why}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _q_accepted(self, handle) -> None:
        """Shown when a page drives (it answers); else aborted at once with the reason, so the client
        can ask elsewhere (the study's terminal)."""
        g = handle.request
        with self.station.lock, self._q_lock:
            busy, driver = self._q_waiting is not None, self.station.link.driver()
            if not busy and driver is not None:
                self._q_next += 1
                q = Questionnaire(self._q_next, g.title, tuple(g.statements), int(g.scale_min),
                                  int(g.scale_max), g.min_label, g.max_label)
                self._q_waiting = (handle, q)
                self.station.link.questionnaire = q
        if busy or driver is None:
            why = ("another questionnaire is waiting on the station" if busy else
                   f"no page drives the operator station (open {self.address})")
            with self._q_lock:
                self._q_outcomes[bytes(handle.goal_id.uuid)] = ("aborted", [], why)
            handle.execute()
            return
        self.get_logger().info(f"questionnaire {q.qid} shown: {len(q.statements)} statements")
        self._q_seen = None
        self._q_feedback()
        self._state(questionnaire=q.to_page())

    def _answered(self, msg: dict, reply) -> None:
        """The driver's answers, checked by the link against the questionnaire that waits."""
        with self._q_lock:
            waiting = self._q_waiting
            if waiting is None or waiting[1].qid != msg["id"]:
                waiting = None
            else:
                self._q_waiting = None
                self._q_outcomes[bytes(waiting[0].goal_id.uuid)] = (
                    "answered", msg["answers"], "answered on the operator station's page")
                self._q_ready.append(waiting[0])
        if waiting is None:   # withdrawn between the link's check and here
            reply({"what": "questionnaire", "ok": False, "message": "the questionnaire was withdrawn"})
            return
        self._state(questionnaire=None)
        reply({"what": "questionnaire", "ok": True, "message": "your answers were sent"})

    def _q_cancel(self, handle) -> CancelResponse:
        """The client withdraws it (the study stopped, or it asks at the terminal now): the pages hide
        it. Refused once the answers are in (they are the result)."""
        with self.station.lock, self._q_lock:
            waiting = self._q_waiting
            if waiting is None or waiting[0].goal_id != handle.goal_id:
                return CancelResponse.REJECT
            self._q_waiting = None
            if self.station.link.questionnaire is waiting[1]:
                self.station.link.questionnaire = None
            self._q_outcomes[bytes(handle.goal_id.uuid)] = ("canceled", [], "withdrawn by the client")
            self._q_ready.append(handle)
        self._state(questionnaire=None)
        return CancelResponse.ACCEPT

    def _q_finish(self) -> None:
        """On the executor (the Joy timer): execute the goals whose outcome is ready (answered or
        canceled)."""
        if not self._q_ready:
            return
        with self._q_lock:
            ready, self._q_ready = self._q_ready, []
        for handle in ready:
            handle.execute()

    def _q_execute(self, handle):
        with self._q_lock:
            kind, answers, message = self._q_outcomes.pop(bytes(handle.goal_id.uuid),
                                                          ("aborted", [], "no outcome"))
        if kind == "answered":
            handle.succeed()
        elif handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
        self.get_logger().info(f"questionnaire {kind}: {message}")
        return QuestionnaireAction.Result(answered=kind == "answered", answers=list(answers), message=message)

    def _q_feedback(self) -> None:
        """The pages open and whether one drives (it can answer), when that changes."""
        with self.station.lock:
            pages = len(self.station.link.clients)
            driver = self.station.link.driver() is not None
        with self._q_lock:
            waiting = self._q_waiting
        if waiting is None or self._q_seen == (pages, driver):
            return
        self._q_seen = (pages, driver)
        text = (f"shown on {pages} page(s); the driving page answers" if driver else
                f"{pages} page(s) open, none drives: nobody can answer")
        waiting[0].publish_feedback(QuestionnaireAction.Feedback(pages=pages, driver=driver, text=text))

    def _publish_status(self) -> None:
        self._q_feedback()
        with self.station.lock:
            counters = self.station.link.counters.as_dict()
            pages = len(self.station.link.clients)
            driving = self.station.link.driver() is not None
        s = DiagnosticStatus(name=NODE_NAME, hardware_id=self.address,
                             message=f"{pages} page(s), {'one drives' if driving else 'nobody drives'}")
        counters.update(**self.station.counters, dropped=self.station.dropped(),
                        frames_received=self.frames.received, frames_encoded=self.frames.encoded,
                        frames_skipped=self.frames.skipped, frames_refused=self.frames.refused,
                        frames_failed=self.frames.failed, frames_sent=self.station.frames_sent,
                        **self.view.fields())
        s.values = [KeyValue(key=k, value=str(v)) for k, v in counters.items()]
        self.status_pub.publish(s)

    def on_shutdown(self) -> None:
        """Zero first, then close the pages."""
        if self.context.ok():
            self._publish_axis(0.0)
        self.station.stop()
        self.frames.stop()

    def destroy_node(self):
        self.on_shutdown()
        self.q_server.destroy()  # rclpy's destroy_node leaves an action server, and its context, alive
        return super().destroy_node()


def _named(values: dict) -> str:
    """The controller's settings in ``values`` in words: "the deadband", "the deadband and the ..."."""
    return " and ".join(cfg.CONTROLLER_SETTINGS[n] for n in values)


def _value(v):
    """A controller parameter's value from its message (a double or a string), None when it has none."""
    if v.type == Parameter.Type.DOUBLE.value:
        return v.double_value
    if v.type == Parameter.Type.STRING.value:
        return v.string_value
    return None


def _cut(text: str) -> str:
    """A peer's status text, cut to TEXT_CHARS characters."""
    return text if len(text) <= TEXT_CHARS else text[: TEXT_CHARS - 1] + "…"


def main(args: list[str] | None = None) -> int:
    return run_node(StationNode, NODE_NAME, args)


if __name__ == "__main__":
    sys.exit(main())
