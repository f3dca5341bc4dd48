"""The reference's prose: what no table says. ``@@name@@`` marks a value taken from the code when rendering."""
# ruff: noqa: E501  (a Markdown table row is one line)
from __future__ import annotations

__all__ = ["SECTIONS"]

TRANSPORT = """\
## Transport and defaults

Zenoh 1.x. Every process joins one fabric: services as *peers*, `fabric-cli` and the console as *clients*,
all connecting to a hub endpoint, by default `tcp/127.0.0.1:7447` (`$FABRIC_HUB` changes it; `fabric-cli up`
and `fabric-cli router` host the hub as a Zenoh router session). Multicast scouting is off unless
`--multicast` is given. A link silent for the lease (1 s by default, `$FABRIC_LEASE_MS`) is dropped, and
with it the liveliness tokens of the processes behind it.

Several cells share one fabric: every key starts with `am/<cell>/`. The default cell is `@@default_cell@@`
(`--cell`, `$FABRIC_CELL`); a cell name matches `@@cell_pattern@@`. On a secured fabric (`fabric-cli auth
init`, `fabric-cli up --secure`) a session joins with a role's Zenoh config; a `monitor` may only ask the
read-only commands (@@monitor_commands@@) and receive telemetry and liveliness.
"""

KEYS = """\
## Keys

| key | what | how |
|---|---|---|
| `am/<cell>/alive/<service>` | a service is up and serving (services: @@services@@) | liveliness token: `liveliness().get` / `declare_subscriber` on `am/<cell>/alive/*`; every cell: `am/*/alive/*` |
| `am/<cell>/<service>/cmd/<command>` | one command (see [Commands](#commands)) | query with the request as payload; one reply |
| `am/<cell>/<service>/cmd/**` | every other key under a service's `cmd/` | the service answers a typed `not_found` at once |
| `am/<cell>/<service>/artifact/<id>` | content-addressed results (see [Artifacts](#artifacts)) | query, no payload; reply `common.Artifact` |
| `am/<cell>/<service>/<topic>` | telemetry (see [Telemetry](#telemetry)) | subscribe |

Keys are built and parsed in one module (`fabric/wire/keys.py`); nothing else in the fabric composes them.
"""

PAYLOADS = """\
## Payloads

Every payload is one **msgpack** map holding the message's fields plus two tags:

| key | meaning |
|---|---|
| `_t` | message type, e.g. `station.Pose` |
| `_v` | schema version (integer; each message's heading gives its current version) |

Field names carry their unit (`_mm`, `_mm3`, `_s`, `_mm_s`, `_deg`, `_rad`, `_c` Celsius, `_r` ratio,
`_bytes`). **Sizes** travel in bytes; this document writes large ones in **MiB**: 1 MiB = 2^20 = 1,048,576
bytes, everywhere (a name ending `_mb`, such as `free_mb` or `$FABRIC_MAX_INPUT_MB`, counts MiB too).
Strings are UTF-8 (msgpack `str`), bytes are msgpack `bin`, nil is msgpack `nil`. Small fixed vectors (a
position, six joints) are msgpack arrays of floats. **Bulk numeric data** (a program's columns) is a
*packed array*: the map `{"nd": true, "dtype": "<f8", "shape": [n, 3], "data": <bin>}`, little-endian,
C order, rebuilt with `numpy.frombuffer(data, dtype).reshape(shape)`; dtypes: @@dtypes@@.

A message carries **every field** of its version, defaults included. A decoder checks the tags, every
field's type and constraints (range, choices, length, the pattern a string matches whole, the most bytes a
`bin` holds: each message's table, and its JSON Schema, state them), and rejects a field it does not know
(keys starting with `_` are ignored). A missing field takes its default; a missing field without one is a
`validation` error naming it.

**Sending `common.Empty`.** A command without arguments still takes a payload: the map with the tags only,
`{"_t": "common.Empty", "_v": 1}`, in msgpack the @@empty_len@@ bytes `@@empty_hex@@`. An empty payload is a
`decode` error with `details.reason` `empty` and `details.expected` the request's type. A service also
takes `common.Empty` for any request whose fields all have defaults (every field then at its default): a
command that grows optional arguments keeps answering older clients.

**Examples in this document** write msgpack as JSON: a map is an object, an array an array, nil `null`.
A msgpack `bin` is written as the string `"bin:"` followed by its content as text (or a placeholder in
angle brackets such as `"bin:<binary STL>"`); in `docs/protocol.json`, whose schemas describe the same
mapping, a `bin` is base64 text.
"""

VERSIONS = """\
## Versions (`_v`)

Each message type has one version number, raised whenever a field is added or a default changes (fields
are never removed, renamed or retyped under the same type name). The rule, on every side:

* a **sender** writes its current version in `_v`, and every field of that version;
* a **receiver** takes versions 1 up to the one it knows: fields the sender did not send take their
  defaults (every field added after version 1 has one), so an older sender is understood;
* a message of a **newer** version than the receiver knows is refused with `decode` (`details.reason`
  `version`, `details.got`, `details.supported`), whatever its type: it may carry a field the receiver
  cannot honour. `common.Empty` is no exception, also where it stands for a request whose fields all have
  defaults: `{"_t": "common.Empty", "_v": 2}` is refused by a receiver that knows version 1. A `_v` that
  is not an integer of at least 1 is refused the same way.

So upgrade services before their clients. A client in another language written against this document
sends the versions listed here; reading, it may ignore fields it does not know, to keep working with
newer services.
"""

COMMANDS = """\
## Commands

A command is a Zenoh **query** on `am/<cell>/<service>/cmd/<command>` whose payload is the request
message. The answer is **one reply**: the reply message, or an **error reply** (`reply_err`) whose
payload is `common.Error` (see [Errors](#errors)). Wait for it at most the command's timeout (table
below); a reply that does not come in that time means the service is busy, frozen or cut off.

**Quality of service.** Commands travel at Zenoh priority `@@cmd_priority@@` and *express* (never held back
to fill a batch), ahead of telemetry; their replies are express too. Ask with consolidation `NONE` and
take the first reply as it arrives: a command has one answering service and one reply, and waiting for
the query's final message would only add its trip back through each hop. *Bulk* commands (their request
or reply can carry megabytes: models, G-code, exports, meshes) and artifact queries travel at the default
`@@bulk_priority@@` priority, batched, with Zenoh's default consolidation, so they never hold up commands.
Query target: Zenoh's default (`BEST_MATCHING`).

**Artifact queries** are in the table too: a query on `am/<cell>/<service>/artifact/<id>` with **no payload**
(see [Artifacts](#artifacts)), answered with `common.Artifact` or `not_found`.

**An unknown command** gets an error reply at once: each service also serves `am/<cell>/<service>/cmd/**`
and answers a key it does not serve with `not_found` (`details.service`, `details.command`,
`details.commands`: the commands it serves). That catch-all stays silent for the commands it serves, and
for wildcard queries, so a command still has exactly one reply. (On a secured fabric the hub drops,
unanswered, a query the session's role may not send: a `monitor` asking anything but its read-only
commands gets no reply; `fabric.client` refuses such a call itself with `forbidden`.)

**When nothing answers** at once, either the service is not running or the cell name is wrong (no
catch-all exists to say `not_found`). Tell them apart with one liveliness query on every cell,
`am/*/alive/*` (answered by the hub): no token of the cell means *no such cell* (list the cells
present), a cell without the service's token means *the service is down*. `fabric.client` does exactly
this and raises `unavailable` with `details.reason`: `no_cell` (`details.cells`: every cell present and
its services), `service_down` (`details.alive`: the cell's services up), `no_reply` (it is up but did not
answer within the timeout) or `no_queryable`. Right after a service starts, its queryables may take a
moment to reach you: the client retries a query that found nobody for up to @@discovery_s@@ s first.

**Health.** Every service answers `<service>/cmd/health` (`common.Health`): `ok`, or `degraded` with its
reasons (an unexpected exception in a handler, a full disk, a failing clock), while it goes on serving.
One query on `am/<cell>/*/cmd/health` gets one reply per running service; `supervisor/status` gathers
them with the liveliness of each.

| key | request | reply | timeout | QoS | what it does |
|---|---|---|---|---|---|
"""

ERRORS = """\
## Errors

An error reply's payload is `common.Error`: `{"code": str, "message": str, "details": map}`. The code is
stable; the message says what went wrong and what to do, for people; the details are plain values to act
on. A service answers malformed payloads with `decode`/`validation` and keeps serving (a `validation`
error always names the `field` and the `schema`); an unexpected failure is `internal` (logged with its
traceback, and the service reports itself degraded). The codes, as `fabric/wire/errors.py` draws them (a
client raises the class of the code):

```
@@error_tree@@
```

The details a caller may rely on, by code (others may be present):

| code | details |
|---|---|
@@error_details@@

**`state` errors** say why a command is refused now: `details.state` (the station's or the job's state)
and `details.command`; a refusal by the station's state also carries `details.allowed`, the states in which
the command is accepted (e.g. `pause` is allowed in `["printing"]`); a refusal because the robot is
moving carries `details.reason` `moving`; a refusal because of the part on the plate carries
`details.plate` (`occupied` or `clear`) and `details.plate_job_id`. A `state` error whose message ends
"nothing was done: ask again" is a lost compare-and-set (the station changed while a move was being
checked): asking again is safe.
"""

INPUTS = """\
## Inputs

A model or a G-code file reaches a service **inline** (the request's `bin` field carries it) or
**uploaded** in pieces first (the request names the upload). Sizes in MiB (2^20 bytes):

| request | inline field | or uploaded to | the most it takes |
|---|---|---|---|
@@input_rows@@

A larger input, inline or uploaded, is a `validation` error naming the field. The supervisor takes a model
(to slice) up to @@model_mib@@ MiB and G-code up to @@gcode_mib@@ MiB, what the slicer and the planner take. An
inline input is held whole at once by the sender, the hub and the service: fabric's client sends an input
larger than @@inline_mib@@ MiB by upload, and a client should do the same.

**Uploads.** Send `upload.Chunk`s to `<service>/upload` in order: offset 0 first (it starts the upload, or
starts it again), then each piece at the offset where the last one ended, at most @@chunk_max_mib@@ MiB each
(fabric's client sends @@chunk_mib@@ MiB); the last piece carries the whole input's `sha256` (hex). Each piece
is answered with `upload.Status`; once it says `done` (the sha256 matched), name the `upload_id` in the
request with the inline field empty. The sender chooses the `upload_id`: 8 to 64 of `A-Za-z0-9_-` (the
pattern is in the schemas). A piece at another offset is a `bad_request` (`details.expected`: the offset
wanted; start again at 0), a wrong sha256 a `bad_request` naming `sha256` (send it again). An upload serves
one request, which removes it: naming it again, or naming one that never finished, is `not_found`. A service
keeps at most @@uploads_kept@@ finished uploads that no request named, and as many unfinished ones (beyond
that the oldest goes), and forgets the unfinished ones when it restarts.
"""

TELEMETRY = """\
## Telemetry

Publications, all `RELIABLE`, at Zenoh's default `@@bulk_priority@@` priority. *Lossless* streams are
published with congestion control `BLOCK` (a slow subscriber slows the publisher rather than miss one);
*sampled* streams with `DROP` (under congestion the latest value wins).

| key | payload | delivery | when |
|---|---|---|---|
@@topic_rows@@

Rates are on the wall clock, whatever the simulation's real-time factor: at `rtf` 0 (as fast as possible)
a pose sample still comes every @@pose_period_ms@@ ms but the events of minutes of printing come in each of
them. Every stream is a snapshot-plus-changes pair with a command: `station/cmd/position`,
`station/cmd/state`, `station/cmd/events`, `supervisor/cmd/job` (and `jobs`), `<service>/cmd/job`. Read the
snapshot after subscribing, so nothing falls in between.

**Frames.** `station.Pose` gives the TCP twice: `xyz_mm` and `quat_wxyz` in the **plate frame** (the work
object: origin at the plate's top-face corner at x min, y min; z up from its surface), and `base_xyz_mm` in
the **robot base frame**; `q_deg` are the joints A1..An in degrees. `station.State.wobj_xyz_mm` and
`wobj_rpy_deg` place the plate frame in the base frame (calibration changes them). Programs, G-code
offsets, the as-printed part and every other position are in the plate frame unless the field says
otherwise.

**Sequence numbers.** `station.Pose.seq` and `station.Extrusion.seq` count the samples of their stream
from 1 for each run of the station process (they restart with it); a gap in `Extrusion.seq` is a lost
message. Events have their own numbering (see [Events](#events)).
"""

TIME_BASES = """\
## Time bases

Three clocks appear in `*_s` fields, and each field's description says which:

* **simulated**: the station's simulated clock (`t_sim_s`: seconds of simulated time since the station's
  twin was first created, kept across restarts, never jumping back; it runs at `rtf` times the wall clock
  and stands still while held) and durations on it (`elapsed_s`, `remaining_s`, `total_s`, `estimate_s`,
  `sim_elapsed_s`);
* **wall clock, epoch**: Unix time in seconds (`created_s`, `updated_s`, `started_s`, `ended_s`,
  `since_s`, `wall_time_s`);
* **wall-clock durations**: how long work took on the computer (`elapsed_s` of slicing, planning and
  sweeps; `wall_elapsed_s`; an event's `stalled_s`).

| field | time base |
|---|---|
@@time_rows@@
"""

STATION_STATES = """\
## Station states

| state | meaning | commands accepted |
|---|---|---|
| `idle` | no program loaded, or its print ended (`reason` `finished` after a finished print) | load, start, home, calibrate, clear_plate |
| `ready` | a program is loaded and not started | start, load, home, calibrate, clear_plate |
| `printing` | the program runs (a move back to a paused or interrupted spot included) | pause, stop |
| `paused` | paused by the operator or the cold-extrusion interlock (the `paused` event comes once the robot is clear) | resume, stop |
| `stopped` | the operator stopped the print (the deposit is kept) | start, load, home, calibrate, clear_plate |
| `interrupted` | the station restarted or stalled mid-print | recover |
| `fault` | the station stopped dead (see `reason`) | start, load, home, calibrate, clear_plate |
| `moving` | reserved for a move outside a print (not sent today) | |

`position`, `state`, `time`, `events`, `ready`, `overrides`, `rtf`, `mesh`, `collisions` (with a program
loaded) and `health` are answered in every state. A command refused in the current state gets a `state`
error with `details.allowed`; `start` and `load` are refused by the plate gate too (see
[Print jobs](#print-jobs)).
"""

EVENTS = """\
## Events

`am/<cell>/station/events` carries every event of the station's twin, lossless, in order. **Numbering**:
`seq` starts at 1 with the station's first event ever (per data folder) and never restarts: it spans every
job, every program and every restart of the station, with **no gaps**. A monitor that sees a gap, or joins
late, asks `station/cmd/events` with `since_seq` (inclusive) for what it missed, then pages on with
`next_seq` until `last_seq`; subscribe first, read the history, then drop the duplicates by `seq`. The
station keeps the last @@keep_events@@ events. `kinds` filters the history by kind.

**Paging** (`station.EventsQuery` -> `station.EventList`): a page holds the events with `seq` >= `since_seq`
(inclusive), oldest first, at most `limit` of them (of `kinds` only, when given); an older `since_seq` than
the oldest event kept starts at the oldest kept (its `seq` shows the gap). `last_seq` is the `seq` of the
newest event logged when the page was read, itself **included**: it is on a page (`since_seq` = `last_seq`
returns it), and reading is complete when `next_seq` > `last_seq`. `next_seq` is the `since_seq` of the next
page: the page's last `seq` + 1. An **empty page** (`events` `[]`, no error) means nothing more to read now
(no event from `since_seq`, or none of `kinds`): its `next_seq` is the larger of `since_seq` and
`last_seq` + 1, its `last_seq` as above (0 while the log is empty). `station/beads` pages by `first` and
`limit` the same way: a page past the end is empty, with `first` = `total`.

Every event has `t_sim_s`, the `row` and `gcode_line` of the program at that moment and the `layer`
(0-based, -1 when none). Events of a print job (@@job_events@@) also carry `job_id` and `elapsed_s`
(simulated seconds since the print started) when its program was loaded for a job.

| kind | when | data |
|---|---|---|
@@event_rows@@
"""

PRINT_JOBS = """\
## Print jobs

`supervisor/submit` (`supervisor.JobSubmit`) queues a print job and answers at once with
`common.JobAccepted` (`kind` `print`); the job is durable from then on. The file to print comes in exactly
one of three ways: inline in `model`; uploaded in pieces to `supervisor/upload` and named by `upload_id`
(`model` empty; see [Inputs](#inputs)), as `fabric-cli job submit` does for a file larger than @@inline_mib@@
MiB; or from the file library by `file_id` (`model` empty). Two of them, or none, is a `validation` error.

**Submit defaults.** `source` empty (the default) is taken from the file name at the supervisor:
@@gcode_suffixes@@ are G-code (planned as they are), @@model_suffixes@@ models (sliced first); any other
name is a `validation` error naming `source`. The print runs at real time (`rtf` 1) unless asked otherwise:
`rtf` 0 runs it as fast as the computer can, 10 at ten times real time. `fabric-cli job submit` has the
same defaults (`--rtf 1`, `--source` from the file name). `start` is false by default: the job is loaded
when its turn comes and waits for the operator's `station/start`.

**Lifecycle.** `state` goes `queued` -> `slicing` (models only) -> `planning` -> `checking` -> `queued` with
`prepared` true -> `loaded` -> `printing` <-> `paused` -> `finished` | `stopped` | `failed`, or
`interrupted` (the station restarted mid-print: `station/recover` goes on, `printing` again). A job that
cannot be prepared (a G-code error, an unreachable target, a collision, cold extrusion) ends `failed` with
its typed `error`. Waiting jobs (`queued`, preparing) can be reordered (`job_move`) and removed
(`job_remove`); a job on the station cannot be removed.

### Print job states

`supervisor.JobRecord.state`, and `JobsQuery.states`:

| state | meaning |
|---|---|
@@print_job_state_rows@@

**Loading and the plate gate.** The station owns the part on the plate: a print's first bead puts a
part there (`station.State.plate_clear` false, `plate_mm3`, `plate_job_id`), and it stays until the
operator says it is off with `station/clear_plate` or `supervisor/job_next` (event `plate_cleared`),
whatever happens to the job or the station, restarts included. The operator's word is noted even when the
station saw the plate clear (a print stopped before its first bead): a job waiting for the plate goes on.
While the plate is occupied the station refuses (`state` error, `details.plate` `occupied`) a print from the beginning, a `load`, and a restart at
a layer of another program's part; a restart at a layer of this program's part is allowed (it adds to
it). A job whose print ended is never started from the beginning again (print it again as a new job, or
go on at a layer). The head of the queue is loaded when it is prepared, the station holds no job (its
state is one of @@station_free@@) and the plate is clear; a prepared job says what it waits for in
`waiting_for`: `queue` (jobs ahead of it), `station` (busy), `plate` (the operator must confirm the plate
is clear).

**`job_next`**: the operator confirms the plate is clear. The supervisor tells the station
(`clear_plate`; refused while a print is on it), then loads the next prepared job. It **honours `start`**:
a job submitted with `start` is started; one submitted without is only loaded (`state` `loaded`), and the
operator starts it with `station/start` (`fabric-cli start`). A job not yet prepared is loaded (and
started, if asked) once it is.

**Following a print job.** The supervisor publishes the whole `supervisor.JobRecord` on
`am/<cell>/supervisor/jobs` on every change, lossless; `supervisor/cmd/job` returns the record now. There is
no `supervisor/progress` topic and no `common.JobStatus` for print jobs. Subscribe to `supervisor/jobs`,
ask `supervisor/cmd/job`, then apply the records of your job as they come. The station's events say the
same things first, with the simulated clock.

**How a finished print shows**: the station publishes the event `finished` (its `data` holds the totals),
its state becomes `idle` with `reason` `finished` and `progress_r` 1 (the part stays on the plate:
`plate_clear` false); the job record becomes `finished` with `ended_s`, `progress_r` 1, `deposited_mm3` and
`filament_mm`. A stopped print shows `stopped` (event, station state and record), a fault `fault` (the
record: `failed`).

**`from_layer`** (`station.StartRequest`): -1 (the default) means not given: `start` runs from the
beginning, `recover` goes back to the interrupted spot. 0 or more is a 0-based layer (as in events;
people count from 1): `start` heats, moves above that layer's first point and prints the rest on the part
already there; `recover` restarts at that layer instead of the interrupted spot. `resume` and `rtf` ignore
it.

**Pagination** of `supervisor/jobs`: `supervisor.JobsQuery` asks `limit` records (default @@jobs_limit@@,
at most @@jobs_max@@) from the `offset`-th (0-based) in queue order, of `states` only when given; the
reply's `total` is how many match in all and `offset` echoes the place of its first record. Page on with
`offset + len(jobs)` until it reaches `total`. A page at or past the end (`offset` >= `total`, or `limit`
0) is empty: `jobs` `[]`, `total` as ever, `offset` as asked (no error). `common.Empty` (what older clients
send) asks the first page. `job_move` answers with the first page of the queue after the move (up to 100
records, and `total`). `supervisor/files` pages the same way (`offset`, `limit`, `total`; an empty page past
the end).

**The file library.** Every file submitted enters the supervisor's library once per content and name
(`supervisor.LibraryFile`: its `file_id`, size, when it was added and last used, how many jobs were made
from it, the last job's id, state, settings and plan figures); `supervisor/file_add` keeps a file without
printing it. `supervisor/files` pages through it, most recently used first (`FilesQuery.name_contains`
filters); `supervisor/file` reads one entry (by its id or a unique start of 6 characters or more);
`supervisor/file_remove` forgets it (the records of its jobs stay). A `JobSubmit` with `model` empty and
`file_id` set prints a library file again (give the settings: the entry's are what its last job used).
A submission that is refused leaves no entry.

**By hand, while no print is on** (station idle, ready, stopped or fault, and not moving):
`station/jog` moves the nozzle straight by a vector in the plate frame (at most 200 mm a command), certified
against the table, the plate and the part first (a hit is a `collision` error of kind `jog`);
`station/extrude` pushes or pulls filament with the robot still, refused below the material's minimum
extrusion temperature (the loaded program's, else 170 C). Events `jogged` and `extruded` say when each ended.
"""

PIPELINE_JOBS = """\
## Slicing and planning jobs

`slicer/slice` and `planner/plan` answer at once with `common.JobAccepted` (`kind` `slice`, `plan`). The
service publishes `common.JobStatus` on `am/<cell>/<service>/progress` on every change of state or stage and
otherwise at most every @@progress_period_s@@ s while it runs; `<service>/cmd/job` returns it now. The job
ends `done` with `result_id` (the G-code's or the program's artifact id) or `failed` with its typed
`error`. `slicer/result` and `planner/summary` give the result's summary by that id. A service keeps the
statuses of its last jobs in memory only: after a restart, ask for the result by its artifact id.

The model or the G-code comes inline or uploaded (see [Inputs](#inputs)); `PlanRequest.gcode_id` names
G-code the slicer made instead.

`common.JobStatus.state`:

| state | meaning |
|---|---|
@@job_state_rows@@
"""

MULTIAXIS = """\
## Multi-axis G-code (curved layers)

A G-code file whose first line is `; multiaxis: nozzle axis in I J K` is in the multi-axis dialect, written
by `fabric-cli slice --layers curved` (`SliceRequest.layers` "curved", built-in back-end only) and by a job
submitted with `layers` "curved" (`fabric-cli job submit part.stl --layers curved`).

- `G1 X Y Z I J K E F` is an extruding move: X Y Z the nozzle tip in the plate frame (mm, absolute, G90);
  I J K the nozzle axis as a unit vector in the plate frame, pointing from the tip up the nozzle (`I0 J0 K1`
  is a vertical nozzle, the tilt is acos K); E filament in mm, relative (M83); F mm/min, modal.
- `G0 X Y Z I J K F` is a travel, with the same meaning.
- The axis is modal like X Y Z (the built-in writer repeats it on every move); readers normalise (I, J, K)
  and a zero vector is an error. In this dialect I J K are never arc offsets (no G2/G3).
- Rotation about the nozzle axis is free: the planner chooses it.
- Markers are those of planar G-code: `;LAYER_CHANGE`, `;Z:` (the layer's highest tip), `;HEIGHT:` (the
  nominal thickness; the real one varies along a curved layer and is carried by E), `;TYPE:`, `;WIDTH:`.
- Header lines `; curved: key = value` state the slice's measured figures (overhang_mm2 and
  planar_overhang_mm2, thickness_min_mm and thickness_max_mm, max_tilt_deg, max_neighbour_deg, cusp_mean_mm,
  ...).
- A reader that does not implement the dialect must not plan the file with a vertical tool.
- The planner plans every move with its own nozzle axis (the TCP's z is minus the axis): a move that turns
  the axis by more than `PlanRequest`'s `max_turn_deg` (default 5 deg) is planned as equal pieces (the point
  along the segment, the axis along the great circle), travel lifts and the approach and return go along the
  nozzle axis, and the reachability report counts every target. `tilt_deg` is refused for such a file. A
  move that only turns the axis (no X Y Z) turns it for the moves after it; arcs and a zero axis are `gcode`
  errors naming their line.
- The program says `meta.multiaxis` true and the bead width (`;WIDTH:`): the twin lays each bead hanging
  along the nozzle axis it was laid with, its height from its flow (`station/beads` carries each bead's
  `axis`), and the collision check orients the part's beads the same way.
- A cell must be able to follow the tilt: on the paper's cell (`irb140`), where a vertical nozzle is ~22 deg
  from the forearm's axis, a nozzle tilted around a part makes A4 turn a full turn per lap (joint jumps);
  the built-in cell `irb140-multiaxis` (the work table 350 mm above the robot base, a slender nozzle) reaches
  every target of the test shapes with one configuration.
"""

ARTIFACTS = """\
## Artifacts

Results are content-addressed: the id is the sha256 (hex) of the bytes. Ask for one with a query on
`am/<cell>/<service>/artifact/<id>` with **no payload** (bulk QoS) and wait for it at most
@@artifact_timeout_s@@ s (the [Commands](#commands) table has a row per service); the reply is
`common.Artifact`, or a `not_found` error. What each service keeps:

| service | media types | artifacts |
|---|---|---|
@@artifact_rows@@

**A program artifact**'s `data` is an encoded `planner.ProgramMsg` (a msgpack map with its own `_t` and
`_v`): its `columns`, one packed array per column with one row per instruction, the work object `wobj`
(4x4, the plate frame in the robot base frame) and free-form `meta`; see `planner.ProgramMsg` for every
column. `planner/export` (whole) and `planner/export_chunk` (streamed) turn a program into ABB RAPID, KUKA
KRL, URScript or CSV; `station/mesh` returns the as-printed part (STL, GLB) or its beads (CSV).
Artifacts a print job needs are pinned (`<service>/pin`) until it ends, so they are not evicted.
"""

PLAIN_CLIENT = """\
## A client with nothing but zenoh and msgpack

```python
import json, msgpack, zenoh

conf = zenoh.Config()
conf.insert_json5("mode", json.dumps("client"))
conf.insert_json5("connect/endpoints", json.dumps(["tcp/127.0.0.1:7447"]))
conf.insert_json5("scouting/multicast/enabled", "false")
EMPTY = msgpack.packb({"_t": "common.Empty", "_v": 1})

def ask(session, key, payload=EMPTY, timeout=5.0):
    for reply in session.get(key, payload=payload, timeout=timeout,
                             priority=zenoh.Priority.INTERACTIVE_HIGH, express=True,
                             consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            return msgpack.unpackb(reply.ok.payload.to_bytes())
        raise RuntimeError(msgpack.unpackb(reply.err.payload.to_bytes()))  # common.Error
    raise TimeoutError(key)      # nobody answered: ask am/*/alive/* which cells exist

with zenoh.open(conf) as session:
    print([str(r.ok.key_expr) for r in session.liveliness().get("am/cell1/alive/*") if r.ok])
    print(ask(session, "am/cell1/station/cmd/position")["xyz_mm"])

    def on_pose(sample):
        pose = msgpack.unpackb(sample.payload.to_bytes())
        print(pose["seq"], pose["t_sim_s"], pose["xyz_mm"], pose["q_deg"])
    session.declare_subscriber("am/cell1/station/pose", on_pose)
    input("press Enter to stop\\n")
```

`tests/test_conformance.py` drives a whole print this way (list the services, read position and state,
follow pose and events without gaps, submit G-code, start, pause, resume, stop), in a process that imports
nothing of this project.
"""

SECTIONS = {"transport": TRANSPORT, "keys": KEYS, "payloads": PAYLOADS, "versions": VERSIONS,
            "commands": COMMANDS, "errors": ERRORS, "inputs": INPUTS, "telemetry": TELEMETRY, "time_bases": TIME_BASES,
            "station_states": STATION_STATES, "events": EVENTS, "print_jobs": PRINT_JOBS,
            "pipeline_jobs": PIPELINE_JOBS, "multiaxis": MULTIAXIS, "artifacts": ARTIFACTS,
            "plain_client": PLAIN_CLIENT}
