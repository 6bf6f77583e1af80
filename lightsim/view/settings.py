"""Settings of ``lightsim view``, declared once: the command's options and the session's tuning.

Every field of :class:`ViewSettings` carries its :class:`~lightsim.options.Option` record
(:mod:`lightsim.options`): ``lightsim view --help``, the range checks and the settings the
live session (:class:`~lightsim.view.live.LiveSession`) reads all come from this table.
Fields with a flag are the command's options (``workers``, ``traffic``, ``resolution`` and
``frame_photons`` share the records of ``simulate``'s options); the others tune the
session thread and are set by tests and benchmarks.

=========================  =====  =======  ==================================================
tuning field               unit   default  meaning
=========================  =====  =======  ==================================================
``batch_seconds``          s      0.05     accumulation: tracing time of the first batch
                                           after an edit (an edit waits at most one batch)
``batch_growth``           –      1.5      … times this per batch
``batch_max_seconds``      s      0.3      … up to this (from ~10⁵ photons a batch traces
                                           at the engine's full rate: larger batches gain
                                           nothing and make an edit wait longer)
``still_batch_photons``    –      5·10⁴    … but, once the scene is still, at least this
                                           many (per-call costs: a batch traces near
                                           the engine's full rate from ~5·10⁴ photons,
                                           which a loaded machine does not fit into
                                           0.3 s; more would make an edit wait ~1 s)
``still_seconds``          s      0.75     the scene is still this long after the last
                                           interaction frame;
                                           before, no estimate, pooled map or table either
                                           (nothing long for a paused drag's next edit to
                                           wait for)
``batch_photons``          –      2²⁰      photons of one batch at most (the session's
                                           frame; memory ≈ 100 B per photon of a batch)
``first_pooled_seconds``   s      1.0      tracing before the first pooled map (or the
                                           pooled map's own cost, if more) while no error
                                           law is known; with one, at the photons where
                                           e √N of the map nearest 5 % predicts 5 % ...
``first_cap_seconds``      s      30       ... but after at most this much tracing (or
                                           twice the pooled map's cost; meanwhile the
                                           interleaved image and grid figure go on)
``pooled_share``           –      0.1      pooled maps at doubled photons take at most this
                                           share of the time (a predicted crossing of
                                           5 %, 2 %, 1 %, 0.5 % is not delayed; none
                                           when the crossing is due before twice the
                                           photons now)
``probe_share``            –      0.1      the grid-probe error figure (only before the
                                           first pooled map) takes at most this share
``regulation_interval``    s      1.0      regulation table refresh once the scene is still
``regulation_share``       –      0.05     … and at most this share of the time (its kNN
                                           trees cost ~0.3–0.8 µs per new photon)
``stop_error``             –      0.005    accumulation stops (idles) at this error figure
``max_photons``            –      2·10⁸    … or at this many photons
``memory_share``           –      0.5      … or when the photon maps (at their insertion
                                           peak, ``engine.memory``) hold this share of the
                                           memory available at the last change (a still
                                           scene would otherwise fill the machine)
``quick_photons``          –      5 000    photons of an interaction frame after an edit (at
                                           most the frame's photons): the low-quality frame
``frame_seconds``          s      0.18     … fewer if the tracer's measured rate does not
                                           fit them into this beside the frame's render,
                                           update and encode (a drag at ≥ 5 frames/s)
``min_photons``            –      3 000    … but at least this many
``interaction_step``       px     2        interaction frames render the interleaved image
                                           at every 2nd pixel (¼ of the kNN queries; the
                                           page scales it to the wall's size)
``settle_seconds``         s      0.45     after an interaction frame, wait this long for the
                                           next edit before accumulating (an edit then
                                           need not wait for a batch in progress)
``warm_up``                –      True     run every code path once before ``ready`` is
                                           set (numba kernels compiled, no edit JITs)
``threads``                –      auto     numba threads of the session thread; auto = the
                                           warm-up times interaction frames and
                                           accumulation batches at 1 and at all threads
                                           and keeps the faster for each (on an
                                           oversubscribed machine the parallel kernels'
                                           barriers cost more than the second core gives);
                                           still batches revise the accumulation's (a
                                           still scene's first batch and one in 8 at the
                                           other count; moving average of the rates)
=========================  =====  =======  ==================================================
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from lightsim import options
from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.options import option
from lightsim.simulate import SimulateOptions

TUNING = "tuning of the session thread (set by tests and benchmarks)"


def shared(cls: type, name: str, **change: Any) -> Any:
    """A dataclass field carrying the record of option ``name`` of ``cls`` (same flag,
    help and range); ``change`` may set another default (the help then says it)."""
    opt = options.lookup(cls, name)
    if "default" in change:
        opt = dataclasses.replace(opt, default=change.pop("default"), default_text=None)
    if change:
        raise TypeError(f"unknown change(s): {', '.join(change)}")
    return dataclasses.field(default=opt.default, metadata={"option": opt})


@dataclass(frozen=True)
class ViewSettings:
    """Everything ``lightsim view`` and its live session depend on (see the module
    docstring: the tuning fields' table; the command's options are in ``--help``)."""

    # -- the command line ---------------------------------------------------------------
    workers: int = shared(SimulateOptions, "workers")
    address: str | None = option(None, "Ray cluster address HOST:PORT (instead of --workers).",
                                 flag=("--address",))
    host: str = option("127.0.0.1", "Address to listen on: 127.0.0.1 (this machine only), "
                       "or an address or name of this machine (0.0.0.0 = all) to open the "
                       "page from another one; always with the printed access token, "
                       "unencrypted unless tunnelled.", flag=("--host",))
    port: int = option(8765, "Port to listen on (0 = any free port).", flag=("--port",),
                       low=0, high=65535)
    max_upload_mb: float = option(512.0, "Largest scene upload; a larger one is refused "
                                  "before it is read.", unit="MB", flag=("--max-upload",),
                                  low=0, low_open=True)
    regulation: str | None = option("r112-b-passing", "Rule set drawn on the pattern "
                                    "('none' for no table).", flag=("--regulation",))
    traffic: str = shared(SimulateOptions, "traffic")
    resolution: tuple[int, int] = shared(SimulateOptions, "resolution")
    frame_photons: int = shared(RunConfig, "frame_photons", default=20_000)  # a control too
    out_dir: str = option("lightsim-view", "Session folder: edits.jsonl, state.json, saved "
                          "runs.", flag=("--out",), kind="dir")
    state_file: str | None = option(None, "Restore the controls of a state.json (e.g. after "
                                    "a crash).", flag=("--state",), kind="file")
    camera: bool = option(True, "The camera tab (the lamp seen from above and behind).",
                          flag=("--camera/--no-camera",), kind="onoff")
    camera_resolution: tuple[int, int] = option(
        (400, 200), "Image size of the camera tab.", unit="px", kind="pair", low=1,
        internal="set by tests and benchmarks")

    # -- the session thread's tuning ----------------------------------------------------
    batch_seconds: float = option(0.05, "Tracing time of the first batch after an edit.",
                                  unit="s", low=0, low_open=True, internal=TUNING)
    batch_growth: float = option(1.5, "Growth of the batch time per batch.", low=1,
                                 internal=TUNING)
    batch_max_seconds: float = option(0.3, "Largest batch time (at least batch_seconds).",
                                      unit="s", low=0, low_open=True, internal=TUNING)
    batch_photons: int = option(1 << 20, "Photons of one batch at most (the session's "
                                "frame).", low=1, internal=TUNING)
    first_pooled_seconds: float = option(1.0, "Tracing before the first pooled map while "
                                         "no error law is known.", unit="s", low=0,
                                         internal=TUNING)
    first_cap_seconds: float = option(30.0, "Tracing before the first pooled map at most.",
                                      unit="s", low=0, internal=TUNING)
    pooled_share: float = option(0.1, "Share of the time pooled maps at doubled photons "
                                 "take at most.", low=0.01, high=0.9, internal=TUNING)
    probe_share: float = option(0.1, "Share of the time the grid-probe figure takes at "
                                "most.", low=0.01, high=0.9, internal=TUNING)
    regulation_interval: float = option(1.0, "Regulation table refresh once the scene is "
                                        "still.", unit="s", low=0, internal=TUNING)
    regulation_share: float = option(0.05, "Share of the time the regulation table takes "
                                     "at most.", low=0.01, high=0.9, internal=TUNING)
    stop_error: float = option(0.005, "Accumulation stops at this error figure.", low=0,
                               internal=TUNING)
    max_photons: int = option(200_000_000, "Accumulation stops at this many photons.",
                              low=1, internal=TUNING)
    quick_photons: int = option(5_000, "Photons of an interaction frame after an edit.",
                                low=1, internal=TUNING)
    frame_seconds: float = option(0.18, "Time an interaction frame's photons should fit "
                                  "into.", unit="s", low=0, internal=TUNING)
    min_photons: int = option(3_000, "Photons of an interaction frame at least.", low=1,
                              internal=TUNING)
    still_seconds: float = option(0.75, "The scene is still this long after the last "
                                  "interaction frame.", unit="s", low=0, internal=TUNING)
    memory_share: float = option(0.5, "Accumulation stops when the photon maps hold this "
                                 "share of the available memory.", low=0, high=1,
                                 low_open=True, internal=TUNING)
    warm_up: bool = option(True, "Run every code path once before the session is ready.",
                           kind="flag", internal=TUNING)
    threads: int | str = option("auto", "numba threads of the session thread (auto: the "
                                "faster of 1 and all, timed).", cast=str, internal=TUNING)
    settle_seconds: float = option(0.45, "Wait this long after an interaction frame before "
                                   "accumulating.", unit="s", low=0, internal=TUNING)
    interaction_step: int = option(2, "Interaction frames render every n-th pixel.",
                                   unit="px", low=1, internal=TUNING)
    still_batch_photons: int = option(50_000, "Photons of a still scene's batch at least.",
                                      low=0, internal=TUNING)

    def __post_init__(self) -> None:
        options.check_fields(self)  # choices and ranges, from the declarations above
        if not self.host.strip() or any(c.isspace() or c in "/?#@" for c in self.host):
            raise InputError(f"--host must be an address or a host name, got {self.host!r}")
        if self.workers and self.address:
            raise InputError("give --workers or --address, not both")
        if self.threads != "auto" and (isinstance(self.threads, bool)
                                       or not isinstance(self.threads, int)
                                       or self.threads < 1):
            raise InputError(f"threads must be 'auto' or ≥ 1, got {self.threads!r}")
        if self.batch_max_seconds < self.batch_seconds:
            raise InputError(f"batch_max_seconds ({self.batch_max_seconds:g} s) must be at "
                             f"least batch_seconds ({self.batch_seconds:g} s)")

    def with_(self, **changes: Any) -> ViewSettings:
        """A copy with ``changes`` (checked again)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_command_line(cls, values: dict[str, Any]) -> ViewSettings:
        """Settings from the click values of ``click_options(ViewSettings)`` (parsed and
        checked by the options' callbacks); ``--regulation none`` means no table."""
        if values.get("regulation") == "none":
            values = {**values, "regulation": None}
        return cls(**values)
