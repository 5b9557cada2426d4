"""The register map as the Markdown page ``docs/plc_register_map.md`` (``python -m cellctl.plc --write PATH``)."""

from __future__ import annotations

from cellctl.cell.alarms import RECOVERY_COMMANDS
from cellctl.config.cell import ProcessConfig
from cellctl.config.plc import PlcConfig
from cellctl.config.store import PackMLConfig
from cellctl.domain import AlarmCode, PackMLState
from cellctl.plc.connections import MAX_CONNECTIONS
from cellctl.plc.register_map import (
    BLOCKS,
    CELL_BLOCK,
    COMMAND_REPLY_TEXT,
    MAP_VERSION,
    PLC_BLOCK,
    PLC_ERROR_CODE_RANGE,
    PLC_ERROR_TEXT,
    STORED_REFUSALS,
    UNIT_ID_EXCEPTION,
    Block,
    CommandReply,
    PlcErrorCode,
)

SIM_END_POSE_WALL_MM = 389
"""The simulated cell's flange-to-wall distance (mm) at the end of a normal cycle (the last flush reading)."""

_INTRO = """\
# PLC register map (Modbus TCP)

Generated from `src/cellctl/plc/register_map.py` by `python -m cellctl.plc --write
docs/plc_register_map.md`; do not edit by hand (a test compares this file with the generator).

Map version {major}.{minor}. The cell is the Modbus TCP server (host, port and unit id from `[plc]` in
the config). All values are holding registers at 0-based protocol addresses (address 0 is 40001
in Modicon notation): read with FC3, write with FC16 (or FC6, FC22, FC23). Every other function code
(coils, input registers, diagnostics FC8, FC7, FC11, FC17, FC43) gets exception code 1 (illegal
function); one of these five whose quantity or length is out of range (FC3 reads 1-125 registers) gets
exception code 3 (illegal data value). An exception answer carries the request's function code + 0x80.

- The **PLC block** ({p_start}-{p_last}) is written only by the PLC; the cell only reads it. One client
  writes it: the line PLC. A second client (an HMI, a diagnostics tool) must only read (FC3): the cell
  does not tell writers apart, so a second writer's zeros drop the PLC's request before its `done`, and
  its heartbeat hides a dead PLC. `[plc] allowed_clients` restricts by address who may connect at all
  (list the PLC and the HMI; firewall the port).
- The **cell block** ({c_start}-{c_last}) is written only by the cell. A PLC write into it is refused
  with exception code 2 (illegal data address), leaves it unchanged and counts in
  `refused_write_count`, also when it starts below the block (a write offset too low). Addresses
  between the blocks do not exist (exception code 2, not counted), so read and write each block with
  its own request.
- Reserved addresses of the cell block read 0. Reserved addresses of the PLC block are not read by
  the cell and keep what a client writes there: write 0 to them (or leave them out of the write), as a
  later map version may give them a meaning.
- 32-bit values (uint32, float32) take two registers; their word order is `[plc] float_word_order`:
  `big` puts the high word first (ABCD), `little` the low word first (CDAB). Bytes within a
  register are always big-endian.
- **Unit id.** The cell answers the unit id `[plc] unit_id` (default 1). A request to any other
  unit id reads and writes nothing and gets exception code {unit_exc} (gateway target device failed
  to respond); the cell logs a warning naming the unit id (the first time, then every 1000th).
  With `unit_id = 0` the cell answers every unit id.
- **Connections.** Requests may be pipelined: the cell answers every complete frame a connection
  sends, in order, each with its transaction id. A frame with a protocol id other than 0 or an MBAP
  length outside 2-254 closes the connection, after the frames before it are answered. A connection
  without a request for `[plc] idle_timeout_s` (default {idle_s:g} s, or twice
  `heartbeat_timeout_s` if that is longer) is closed, and TCP keepalive drops
  one whose peer vanished: poll on the connection the PLC keeps (every scan), or let its Modbus client
  reconnect. The cell holds at most {max_conn} connections (fewer with a low open files limit: an
  eighth of it), a quarter of them from one address; beyond that it closes the connection that has
  gone longest without a request, or refuses the new one.

## Start-up and states

`state_current` is the PackML state (PackTags numbers, listed with the register). After every
start of the service the cell is in **{initial_state}** (`state_current` = {initial_state_id};
`[packml] initial_state`, default `{initial_state_cfg}`, may say `stopped` instead): it never
resumes running by itself. To produce, send the PackML commands Clear (9), Reset (1) and Start (2),
each once the state before has settled:
{start_path}.

`ready` is 1 only in Execute (`state_current` = 6), while no cycle request is being served and
`cycle_request` = 0; in every other state it is 0, and a cycle request there is refused with
`error_code` {not_ready} (stored like any refusal). A cycle requested over the REST API in
Execute runs first; the PLC's request then waits behind it (`busy`).

`robot_clear` (a `cycle_flags` bit) tells the line when it may move the car body: no cycle runs and
the robot's flange stands at least `[plc] clear_distance_mm` (default {clear_mm:g} mm) in front of the
car body's wall. The cell measures it from the robot's reported flange pose against the wall plane
the last cycle fitted; the integrator commissions `clear_distance_mm` from the cell's layout (the
gripper's length, the car body's contour, the robot's end pose). At `done` the robot still stands
where the cycle's last laser reading left it, in front of the car body (in the simulated cell
{end_mm:g} mm from the wall): move the car body only once `robot_clear` = 1. It is 0 while a cycle
runs, after a cycle that did not end done (a failed, stopped or aborted one, above all one aborted
during the install: see `install_started`), and whenever the robot's pose or the wall is not known
(the robot's link is down, or no cycle has ended done yet); then a person decides whether the car
body may move.

A unit mode request (`unit_mode_request`, 1 production, 2 maintenance, 3 manual) is taken only
in the states of `[packml] mode_change_states`, by default {mode_states};
in any other state the cell answers `unit_mode_result` = 1 (invalid in this state) and the mode
stays. A PackML command the state model does not allow in the current state gets `cmd_result` =
1 the same way ([PackML states](packml_states.md)). A command the state model allows but an
interlock holds back gets `cmd_result` = {blocked} (blocked), and the cell's log names the interlock:
{recovery} while an alarm with a reaction is active ([alarm reactions](alarm_reactions.md)),
Complete while a cycle runs, Start while a commissioning job runs. The first such alarm's id stands
in `interlock_alarm_id` in any state (in Idle, say, where a lost laser stops nothing and
`stop_reason_id` stays 0).

## Handshakes

**Heartbeats.** The PLC changes `plc_heartbeat` periodically; if it stays unchanged for
`heartbeat_timeout_s` the cell raises "PLC heartbeat lost" (alarm {hb_alarm}, with `[plc]
heartbeat_alarm` on: Hold when the robot stands still, Abort while it moves; a cycle stopped by
it ends `nok` with `error_code` {hb_alarm}) and clears `plc_heartbeat_ok`. The cell increments
`cell_heartbeat` every `cell_heartbeat_period_s`; the PLC should watch it the same way.

**Cycle** (four-way, keyed by `cycle_req_id`):
1. With `ready` = 1, the PLC writes `recipe_id`, `part_id`, `car_body_id` (0 if none), a new nonzero
   `cycle_req_id` and `cycle_request` = 1 in one FC16 write.
2. The cell echoes the id in `cycle_ack_id` and sets `busy` (or, if it refuses, `done` + `nok`
   with `error_code`).
3. When the cycle ends the cell writes the result registers (`result_req_id` = the id) and sets
   `done` with `ok` or `nok`, clearing `busy`, in one update. With `nok`, `install_started` = 1 says
   the robot had begun to install the glass (it may be in the opening or half in it: check the car
   body before it moves on); 0 says the glass never left the cell's side.
4. The PLC reads the result and sets `cycle_request` = 0; the cell then clears `done`, `ok`, `nok`,
   `replayed` and `install_started`. The result registers keep the last result.
5. Before the line moves the car body on, it waits for `robot_clear` = 1 (see Start-up and states).

**A new id while `cycle_request` stays 1.** The cell takes one request at a time. If the PLC writes
a new `cycle_req_id` without dropping `cycle_request` (the running one's `done` not yet read), the
cell first ends the running cycle as in step 3 (`done`, its result registers, perhaps for one scan
only), then takes the new id as a new request: it clears `done`, echoes the new id in `cycle_ack_id`
with `busy`, and publishes its result as usual (`ready` stays 0 meanwhile). The earlier id's result
stays readable: repeat that id to have it published again. Write a new id only for a new car body.

A repeated `cycle_req_id` never starts a second cycle: the cell publishes that id's stored result
again with `replayed` = 1. A refusal is that id's result too (refused by the cell: codes
{stored_codes} and the cell's own ids): repeating the id republishes the refusal, so a refused
request needs a new id. Only the interface's codes {unstored_codes} are not results: repeating
that id asks the cell again. Dropping `cycle_request` before `done` does not cancel a cycle: send
the PackML Stop or Abort command for that.

**A PLC that restarts.** Keep the id of the request in flight (and the next id) in retained memory.
After a restart, while that id has not been answered: request the **same** id again with the same
recipe, part and car body (`cycle_request` = 1) and wait for `done` with `cycle_ack_id` = that id,
as for any request. If its cycle still runs the cell answers `busy` with that id, then `done`; if it
has ended, the cell publishes its stored result at once (`replayed` = 1). A `done` that came while
`cycle_request` was 0 (the PLC's restart wrote 0) is cleared at once: asking again is the only way to
read it. Never give the same car body a new id: a new id runs a new cycle and installs a second
glass. `result_req_id` shows which id the result registers belong to.

**PackML commands and unit mode.** The PLC writes `cntrl_cmd` and sets `cmd_change_request` = 1;
the cell answers with `cmd_ack_cmd`, `cmd_result` and `cmd_ack` = 1; the PLC sets
`cmd_change_request` = 0 and the cell clears `cmd_ack`. The unit mode uses `unit_mode_request`,
`unit_mode_change_request`, `unit_mode_ack_mode`, `unit_mode_result` and `unit_mode_ack` the
same way.

## Recipes

`recipe_id` must be the `id` of one of the config's `[[process.recipes]]` tables (each has an `id`
1-65535, the number the PLC sends, and a `name`, which the cycle records and the REST API use).
Any other `recipe_id` is refused with `error_code` {unknown_recipe}, and a recipe the cell has not
been taught yet, or whose own teaching or nine-point map is not ready, with {not_taught}. A config without `[[process.recipes]]` has this one (the
simulated cell's `config/sim.toml` lists its own: 1 side-window and 2 door-window):

| recipe_id | name | description |
|---|---|---|
{recipes}
"""


def _table(block: Block) -> list[str]:
    lines = [
        f"## {block.name[0].upper()}{block.name[1:]}: {block.start}-{block.end - 1}, "
        f"written by the {block.access.value}",
        "",
        "| Address | Name | Type | Units | Description |",
        "|---|---|---|---|---|",
    ]
    for reg in sorted(block.registers, key=lambda r: r.address):
        addr = str(reg.address) if reg.words == 1 else f"{reg.address}-{reg.end - 1}"
        desc = reg.description.replace("|", "\\|")
        lines.append(f"| {addr} | `{reg.name}` | {reg.type.label} | {reg.units} | {desc} |")
    used = {a for r in block.registers for a in range(r.address, r.end)}
    free = [a for a in range(block.start, block.end) if a not in used]
    if free:
        lines.append("")
        lines.append(f"Reserved: {_ranges(free)}.")
    for reg in block.registers:
        if reg.bits:
            lines += ["", f"### `{reg.name}` bits", "", "| Bit | Name | Meaning |", "|---|---|---|"]
            for bit in sorted(reg.bits, key=lambda b: b.index):
                lines.append(f"| {bit.index} | `{bit.name}` | {bit.description} |")
    return lines


def _ranges(addresses: list[int]) -> str:
    """Sorted addresses as "a-b, c" spans."""
    spans: list[list[int]] = []
    for a in addresses:
        if spans and a == spans[-1][1] + 1:
            spans[-1][1] = a
        else:
            spans.append([a, a])
    return ", ".join(str(lo) if lo == hi else f"{lo}-{hi}" for lo, hi in spans)


def _codes() -> list[str]:
    lines = ["## Codes", "", "`cmd_result` and `unit_mode_result`:", "", "| Value | Name | Meaning |", "|---|---|---|"]
    lines += [f"| {m.value} | `{m.name.lower()}` | {COMMAND_REPLY_TEXT[m]} |" for m in CommandReply]
    lines += ["", f"`error_code` values of the PLC interface itself ({PLC_ERROR_CODE_RANGE.start}-"
              f"{PLC_ERROR_CODE_RANGE.stop - 1}); every other nonzero value is the cell's alarm / stop-reason "
              "id: the first-out alarm that failed or stopped the cycle, e.g. "
              f"{int(AlarmCode.PLC_HEARTBEAT_LOST)} PLC heartbeat lost or {int(AlarmCode.ROBOT_FAULT)} robot fault "
              "(all of them: [alarm reactions](alarm_reactions.md)). \"Stored\": the code is that id's result, and repeating "
              "the id republishes it with `replayed` = 1.",
              "", "| Value | Name | Stored | Meaning |", "|---|---|---|---|"]
    lines += [f"| {m.value} | `{m.name.lower()}` | {'yes' if m in STORED_REFUSALS else 'no'} | {PLC_ERROR_TEXT[m]} |"
              for m in PlcErrorCode]
    return lines


def _code_list(codes: list[PlcErrorCode]) -> str:
    return ", ".join(str(int(c)) for c in sorted(codes))


def render_markdown() -> str:
    """The register map as the Markdown page committed at ``docs/plc_register_map.md``."""
    packml = PackMLConfig()
    initial = PackMLState[packml.initial_state.upper()]
    path = [PackMLState.ABORTED, PackMLState.CLEARING, PackMLState.STOPPED, PackMLState.RESETTING,
            PackMLState.IDLE, PackMLState.STARTING, PackMLState.EXECUTE]
    if initial is not PackMLState.ABORTED:
        path = path[path.index(initial):]
    mode_states = sorted(PackMLState[s.upper()] for s in packml.mode_change_states)
    text = _INTRO.format(
        major=MAP_VERSION[0], minor=MAP_VERSION[1],
        p_start=PLC_BLOCK.start, p_last=PLC_BLOCK.end - 1,
        c_start=CELL_BLOCK.start, c_last=CELL_BLOCK.end - 1,
        unit_exc=UNIT_ID_EXCEPTION,
        initial_state=initial.name.title(), initial_state_id=int(initial), initial_state_cfg=packml.initial_state,
        start_path=" -> ".join(f"{s.name.title()} ({int(s)})" for s in path),
        not_ready=int(PlcErrorCode.NOT_READY), unknown_recipe=int(PlcErrorCode.UNKNOWN_RECIPE),
        not_taught=int(PlcErrorCode.RECIPE_NOT_TAUGHT),
        mode_states=", ".join(f"{s.name.title()} ({int(s)})" for s in mode_states),
        stored_codes=_code_list(sorted(STORED_REFUSALS)),
        unstored_codes=_code_list([c for c in PlcErrorCode if c not in STORED_REFUSALS]),
        recovery="the recovery commands " + ", ".join(f"{c.name.title()} ({int(c)})" for c in sorted(RECOVERY_COMMANDS)),
        hb_alarm=int(AlarmCode.PLC_HEARTBEAT_LOST), blocked=int(CommandReply.BLOCKED),
        clear_mm=PlcConfig().clear_distance_mm, end_mm=SIM_END_POSE_WALL_MM,
        idle_s=PlcConfig().idle_after_s, max_conn=MAX_CONNECTIONS,
        recipes="\n".join(f"| {r.id} | `{r.name}` | {r.description or '-'} |" for r in ProcessConfig().recipes),
    )
    parts = [text]
    for block in BLOCKS:
        parts.append("\n".join(_table(block)) + "\n")
    parts.append("\n".join(_codes()) + "\n")
    return "\n".join(parts)
