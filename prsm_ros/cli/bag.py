"""`prsm-bag`: inspect, export, report on, replay, lay out (Foxglove) and convert ROS 2 MCAP recordings.

    prsm-bag info BAG [--json] [--parameters] [--check | --no-check]
    prsm-bag export BAG -t TOPIC [-t TOPIC ...] -o OUT [--start S] [--end S] [--resample HZ] [--method linear|hold] [--merge]
    prsm-bag report BAG [-o DIR] [--json] [--dynamic-load-rating-n N] [--screw-joint NAME] [--nut-joint NAME]
    prsm-bag report DIR|GLOB -o DIR [--address HOST:PORT]   (many bags → DIR/fleet.parquet; on Ray if installed)
    prsm-bag compare A_DIR B_DIR [--threshold 0.05] [--json] [--fail-on-regression]
    prsm-bag play BAG [--rate R] [--start S] [--end S] [-t TOPIC ...] [--no-clock] [--delay S] [--wait-for-subscribers]
    prsm-bag layout BAG [-o FILE.json] [--screw-joint NAME] [--nut-joint NAME]   (a Foxglove layout)
    prsm-bag serve BAG [--port N] [--host H] [--rate R] [--loop] [--no-wait]   (live to Foxglove, WebSocket)
    prsm-bag to-rrd BAG -o FILE.rrd [--screw-joint NAME] [--nut-joint NAME] [--joint-states-topic T]
    prsm-bag repair BAG OUT.mcap   (a killed recording's bag → a finished file every MCAP reader opens)

BAG is an .mcap file (ours or any ROS 2 recorder's) or a rosbag2 directory holding one. Times
given with --start/--end are seconds from the bag's first message. Progress goes to stderr; a
bad file, bag or argument gives one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from prsm_sim import __version__

from prsm_ros.bag.reader import BagError, open_bag
from prsm_ros.interface import NUT_JOINT, SCREW_JOINT
from prsm_ros.json_out import dumps
from prsm_ros.live.serve_bag import add_parser as add_serve_parser
from prsm_ros.interrupts import interrupt_handled

EXIT_ERROR = 2  # a user error: a bad argument, file or bag (the one exit status of every prsm tool)
INFO_CHECK_MAX_MESSAGES = 100_000  # info decodes every message of a bag up to this size (~20 s) unless told
EXIT_REGRESSION = 3  # compare --fail-on-regression found one


def _print_json(obj) -> None:
    print(dumps(obj))


def info_dict(bag) -> dict:
    start, end = bag.start_ns, bag.end_ns
    return {
        "path": str(bag.path), "size_bytes": bag.path.stat().st_size, "complete": bag.complete, "note": bag.note,
        "profile": bag.profile, "library": bag.library, "messages": bag.message_count,
        "start_s": None if start is None else start * 1e-9, "end_s": None if end is None else end * 1e-9,
        "duration_s": None if start is None else (end - start) * 1e-9,
        "run": {k: v for k, v in bag.run_metadata.items() if not k.endswith("_yaml")},
        "metadata_records": sorted(bag.metadata),
        "topics": [{"topic": t.topic, "type": t.type, "count": t.count, "rate_hz": t.rate_hz,
                    "first_s": None if t.first_ns is None else t.first_ns * 1e-9,
                    "last_s": None if t.last_ns is None else t.last_ns * 1e-9,
                    "encoding": f"{t.schema_encoding}/{t.message_encoding}",
                    "malformed": t.malformed, "problem": t.problem} for t in bag.topics.values()],
        "commands": command_counts(bag),
    }


COMMAND_COUNTERS = ("commands_received", "commands_accepted", "rejected_non_finite", "rejected_malformed",
                    "rejected_inactive_interface", "saturated", "commands_superseded", "commands_refused_not_owner")


def command_counts(bag) -> dict | None:
    """The node's command counters at its last /diagnostics in the bag (None: no prsm-node diagnostics).

    The bag records the commands the node took from its readers; `commands_superseded` are those a
    writer sent that its reader's queue replaced before the node took them (never in the bag)."""
    if "/diagnostics" not in bag.topics:
        return None
    last = None
    for m in bag.messages(["/diagnostics"]):
        for st in getattr(m.msg, "status", ()):
            if str(getattr(st, "name", "")).endswith(": simulation"):
                last = {kv.key: kv.value for kv in st.values}
    if last is None:
        return None
    return {k: (int(last[k]) if last[k].isdigit() else last[k]) for k in COMMAND_COUNTERS if k in last}


def _info_checked(args) -> dict:
    """`info_dict` of the bag, its messages decoded when asked (or the bag is small): `checked` says which."""
    bag = open_bag(args.bag)
    check = args.check if args.check is not None else bag.message_count <= INFO_CHECK_MAX_MESSAGES
    if check:
        bag.check(progress=True)
    d = info_dict(bag)
    d["checked"] = check
    if not check:  # not known, rather than none
        for t in d["topics"]:
            t["malformed"] = None
    if args.parameters:
        d["parameters_yaml"] = bag.run_metadata.get("parameters_yaml")
        d["node_parameters_yaml"] = bag.run_metadata.get("node_parameters_yaml")
    return d


def _print_info_head(d: dict) -> None:
    """The file, its time span, run metadata and command counters, one line each."""
    print(f"file:      {d['path']} ({d['size_bytes'] / 1e6:.2f} MB){'' if d['complete'] else '  UNFINISHED'}")
    if d["note"]:
        print(f"note:      {d['note']}")
    print(f"profile:   {d['profile'] or '(none)'}   library: {d['library'] or '(none)'}")
    if d["duration_s"] is not None:
        print(f"time:      {d['start_s']:.6f} s → {d['end_s']:.6f} s (duration {d['duration_s']:.3f} s)")
    print(f"messages:  {d['messages']}")
    if d["run"]:
        print("run:       " + ", ".join(f"{k}={v}" for k, v in d["run"].items()))
    else:
        print("run:       no prsm_run metadata (recorded elsewhere)")
    print(f"metadata:  {', '.join(d['metadata_records']) or '(none)'}")
    if d["commands"]:
        print("commands:  " + ", ".join(f"{k.removeprefix('commands_')} {v}" for k, v in d["commands"].items())
              + "  (the node's last /diagnostics; superseded: replaced in a reader's queue, not in the bag)")


def _print_info_topics(d: dict) -> None:
    """The table of topics: type, count, rate and malformed messages (when counted)."""
    width = max((len(t["topic"]) for t in d["topics"]), default=5)
    twidth = max((len(t["type"]) for t in d["topics"]), default=4)
    print(f"\n{'topic':<{width}}  {'type':<{twidth}}  {'count':>8}  {'rate':>10}  {'malformed':>9}")
    for t in sorted(d["topics"], key=lambda t: t["topic"]):
        rate = f"{t['rate_hz']:.1f} Hz" if t["rate_hz"] else "-"
        bad = "undecodable" if t["problem"] else (str(t["malformed"]) if d["checked"] else "-")
        print(f"{t['topic']:<{width}}  {t['type']:<{twidth}}  {t['count']:>8}  {rate:>10}  {bad:>9}")
    if not d["checked"]:
        print(f"malformed messages not counted ({d['messages']} messages; --check decodes every one)")


def _cmd_info(args) -> int:
    d = _info_checked(args)
    if args.json:
        _print_json(d)
        return 0
    _print_info_head(d)
    _print_info_topics(d)
    if args.parameters:
        print("\nparameters:\n" + (d["parameters_yaml"] or "(none recorded)"))
        if d["node_parameters_yaml"]:
            print("node parameters:\n" + d["node_parameters_yaml"])
    return 0


def _note(bag) -> None:
    """What opening the bag recovered or skipped (damaged parts, undecodable topics), on stderr."""
    for n in bag.notes:
        print(f"prsm-bag: note: {n}", file=sys.stderr)


def _reading_notes(bag) -> None:
    """What reading skipped (malformed messages, damaged chunks), on stderr once the command is done."""
    for n in bag.reading_notes():
        print(f"prsm-bag: note: {n}", file=sys.stderr)


def _cmd_export(args) -> int:
    from prsm_ros.bag.export import export
    bag = open_bag(args.bag)
    _note(bag)
    paths = export(bag, args.topic or [], args.output, start_s=args.start, end_s=args.end,
                   resample_hz=args.resample, method=args.method, merge=args.merge, fmt=args.format)
    _reading_notes(bag)
    for p in paths:
        print(p)
    return 0


def _report_options(args) -> dict:
    return {"dynamic_load_rating_n": args.dynamic_load_rating_n, "screw_joint": args.screw_joint,
            "nut_joint": args.nut_joint, "topics": {"joint_states": args.joint_states_topic,
                                                    "reference": args.reference_topic,
                                                    "internal_loads": args.internal_loads_topic}}


def _cmd_report(args) -> int:
    from prsm_ros.bag.fleet import fleet_report, is_fleet
    if is_fleet(args.bag):
        if not args.output:
            raise BagError("many bags: give the folder for the table with -o DIR")
        s = fleet_report(args.bag, args.output, _report_options(args), address=args.address)
        if args.json:
            _print_json(s)
        else:
            print(f"{s['bags']} bags ({s['engine']}), {s['ok']} reported, {s['failed']} failed → {s['table']}")
            for f in s["failures"]:
                print(f"  failed {f['bag']}: {f['error']}")
        return 0
    from prsm_ros.bag.report import report, summary_text
    bag = open_bag(args.bag)
    _note(bag)
    topics = {"joint_states": args.joint_states_topic, "reference": args.reference_topic,
              "internal_loads": args.internal_loads_topic}
    from prsm_ros.bag.report import default_output_dir
    out = Path(args.output) if args.output else default_output_dir(bag.path)
    r = report(bag, out, dynamic_load_rating_n=args.dynamic_load_rating_n,
               screw_joint=args.screw_joint, nut_joint=args.nut_joint, topics=topics, plots=not args.no_plots)
    _reading_notes(bag)
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(dumps(r), encoding="utf-8")
    if args.json:
        _print_json(r)
    else:
        print(summary_text(r))
    return 0


def _cmd_compare(args) -> int:
    from prsm_ros.bag.compare import compare, text
    c = compare(args.a, args.b, _report_options(args), threshold=args.threshold, alpha=args.alpha,
                address=args.address)
    _print_json(c) if args.json else print(text(c))
    return EXIT_REGRESSION if args.fail_on_regression and c["regressions"] else 0


def _cmd_play(args) -> int:
    from prsm_ros.bag.play import play
    bag = open_bag(args.bag)
    _note(bag)
    r = play(bag, rate=args.rate, start_s=args.start, end_s=args.end, topics=args.topic,
             clock=not args.no_clock, delay_s=args.delay, wait_for_subscribers=args.wait_for_subscribers)
    _reading_notes(bag)
    for topic, n in r["published"].items():
        print(f"{topic}: {n}")
    for topic, ty in r["skipped"].items():
        print(f"skipped {topic} ({ty})", file=sys.stderr)
    print(f"played in {r['wall_time_s']:.3f} s wall time at rate {r['rate']}")
    return 0


def _cmd_to_rrd(args) -> int:
    bag = open_bag(args.bag)  # one clear message for a bad file before Rerun is involved
    _note(bag)
    try:
        from prsm_ros.viz.from_bag import bag_to_rrd
    except ImportError as e:
        raise BagError(f"to-rrd needs the Rerun SDK (pip install 'prsm[bag]'): {e}") from None
    try:
        summary = bag_to_rrd(bag, args.output, screw_joint=args.screw_joint, nut_joint=args.nut_joint,
                             topics={"joint_states": args.joint_states_topic, "reference": args.reference_topic,
                                     "internal_loads": args.internal_loads_topic})
    except (ValueError, LookupError) as e:
        raise BagError(str(e)) from None  # the message names the file where it matters
    _reading_notes(bag)
    print(args.output)
    for w in summary["warnings"]:
        print(f"prsm-bag to-rrd: warning: {w}", file=sys.stderr)
    for k, v in summary.items():
        if k not in ("warnings", "notes"):  # notes: printed by _note / _reading_notes
            print(f"  {k}: {v}")
    return 0


def _cmd_repair(args) -> int:
    from prsm_ros.bag.repair import repair
    bag = open_bag(args.bag)
    r = repair(bag, args.output, progress=True)
    for n in r["notes"]:
        print(f"prsm-bag: note: {n}", file=sys.stderr)
    print(f"{r['output']}: {r['messages']} message(s) on {r['topics']} topic(s), with summary and footer")
    return 0


def _cmd_layout(args) -> int:
    bag = open_bag(args.bag)
    _note(bag)
    try:
        from prsm_ros.bag.foxglove_layout import layout_json
    except ImportError as e:
        raise BagError(f"layout needs the Foxglove SDK (pip install 'prsm[foxglove]'): {e}") from None
    text = layout_json(bag, screw_joint=args.screw_joint, nut_joint=args.nut_joint,
                       topics={"joint_states": args.joint_states_topic, "reference": args.reference_topic,
                               "internal_loads": args.internal_loads_topic})
    if args.output:
        Path(args.output).write_text(text + "\n", encoding="utf-8")
        print(args.output)
    else:
        print(text)
    return 0


def _range_args(p) -> None:
    p.add_argument("--start", type=float, metavar="S", help="start, seconds from the bag's first message")
    p.add_argument("--end", type=float, metavar="S", help="end, seconds from the bag's first message")


JOINT_OPTIONS = ("screw_joint", "nut_joint", "joint_states_topic", "reference_topic", "internal_loads_topic")


def _joint_options(p, report_opts, *more: str) -> None:
    """The joint and topic options of `report` (and `more` of its options) on another subcommand."""
    for a in report_opts._actions:
        if a.dest in JOINT_OPTIONS + more:
            p._add_action(a)


def _add_info(sub) -> None:
    """`prsm-bag info`: what a bag holds."""
    p = sub.add_parser("info", help="topics, counts, rates, duration, run metadata")
    p.add_argument("bag")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--parameters", action="store_true", help="also print the recorded parameter set (YAML)")
    p.add_argument("--check", action=argparse.BooleanOptionalAction, default=None,
                   help="decode every message to count the malformed ones (default: for bags of at most "
                        f"{INFO_CHECK_MAX_MESSAGES} messages; a message takes ~0.2 ms)")
    p.set_defaults(func=_cmd_info)


def _add_export(sub) -> None:
    """`prsm-bag export`: topics to CSV or Parquet."""
    p = sub.add_parser("export", help="topics to CSV (one column per field, time in seconds)")
    p.add_argument("bag")
    p.add_argument("-t", "--topic", action="append", help="topic to export (repeat for several)")
    p.add_argument("-o", "--output", required=True, help="a .csv file (one topic, or --merge) or a directory")
    _range_args(p)
    p.add_argument("--resample", type=float, metavar="HZ", help="interpolate numeric columns onto a uniform grid")
    p.add_argument("--method", choices=("linear", "hold"), default="linear",
                   help="resampling: linear interpolation or zero-order hold (default linear)")
    p.add_argument("--merge", action="store_true", help="all topics in one CSV on the resampled grid")
    p.add_argument("--format", choices=("csv", "parquet"), default="csv", help="file format (parquet needs pyarrow)")
    p.set_defaults(func=_cmd_export)


def _add_report(sub) -> argparse.ArgumentParser:
    """`prsm-bag report`: metrics and plots; its parser, whose joint and topic options others share."""
    from prsm_ros.bag.report import DEFAULT_DYNAMIC_LOAD_RATING_N
    p = sub.add_parser("report", help="metrics and PNG plots into a folder (many bags: one Parquet table)")
    p.add_argument("bag", help="a bag, or a directory / glob of many bags")
    p.add_argument("-o", "--output", help="folder for the plots and report.json (default: BAG_STEM_report/ beside "
                   "the bag; many bags: required)")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.add_argument("--dynamic-load-rating-n", type=float, default=None, metavar="N",
                   help="dynamic axial load rating C_a for the L10 life (default: the one the bag's parameters record, "
                        f"else {DEFAULT_DYNAMIC_LOAD_RATING_N:g} N, a catalogue value for a ~30 mm × 5 mm lead roller screw)")
    p.add_argument("--screw-joint", default=SCREW_JOINT, help=f"JointState name of the screw (default {SCREW_JOINT})")
    p.add_argument("--nut-joint", default=NUT_JOINT, help=f"JointState name of the nut (default {NUT_JOINT})")
    p.add_argument("--joint-states-topic", help="JointState topic (default: /joint_states or the only one)")
    p.add_argument("--reference-topic", help="Float64 nut position reference (default: .../nut_position_reference)")
    p.add_argument("--internal-loads-topic", help="Float64MultiArray internal loads (default: .../internal_loads)")
    p.add_argument("--no-plots", action="store_true", help="metrics only")
    p.add_argument("--address", metavar="HOST:PORT", help="many bags: report on this Ray cluster")
    p.set_defaults(func=_cmd_report)
    return p


def _add_compare(sub, report_opts) -> None:
    """`prsm-bag compare`: two groups of bags, with `report`'s joint, topic, rating and cluster options."""
    p = sub.add_parser("compare", help="what changed between two groups of bags, with regression flags")
    p.add_argument("a", metavar="A_DIR", help="the baseline group (a directory or glob of bags)")
    p.add_argument("b", metavar="B_DIR", help="the group compared with it")
    p.add_argument("--threshold", type=float, default=0.05, help="relative worsening of a median flagged (default 0.05)")
    p.add_argument("--alpha", type=float, default=0.05, help="significance of the rank test (default 0.05)")
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument("--fail-on-regression", action="store_true", help=f"exit {EXIT_REGRESSION} when a regression is flagged")
    _joint_options(p, report_opts, "dynamic_load_rating_n", "address")
    p.set_defaults(func=_cmd_compare)


def _add_play(sub) -> None:
    """`prsm-bag play`: republish onto ROS topics."""
    p = sub.add_parser("play", help="republish onto ROS topics at a rate factor, with /clock")
    p.add_argument("bag")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1 = real time)")
    _range_args(p)
    p.add_argument("-t", "--topic", action="append", help="topic to play (repeat; default all)")
    p.add_argument("--no-clock", action="store_true", help="do not publish /clock from the bag time")
    p.add_argument("--delay", type=float, default=0.5, metavar="S",
                   help="wait after creating publishers, for discovery (default 0.5 s)")
    p.add_argument("--wait-for-subscribers", action="store_true",
                   help="then wait (up to 30 s) until every played topic has a subscriber")
    p.set_defaults(func=_cmd_play)


def _add_layout(sub, report_opts) -> None:
    """`prsm-bag layout`: a Foxglove layout."""
    p = sub.add_parser("layout", help="a Foxglove layout (JSON) for this bag's topics")
    p.add_argument("bag")
    p.add_argument("-o", "--output", metavar="FILE.json", help="write the layout here (default: stdout)")
    _joint_options(p, report_opts)
    p.set_defaults(func=_cmd_layout)


def _add_to_rrd(sub, report_opts) -> None:
    """`prsm-bag to-rrd`: a Rerun recording."""
    p = sub.add_parser("to-rrd", help="convert to a Rerun .rrd recording")
    p.add_argument("bag")
    p.add_argument("-o", "--output", required=True, help="the .rrd file to write")
    _joint_options(p, report_opts)
    p.set_defaults(func=_cmd_to_rrd)


def _add_repair(sub) -> None:
    """`prsm-bag repair`: a finished copy of an unfinished or damaged bag."""
    p = sub.add_parser("repair", help="rewrite an unfinished or damaged bag as a finished one (summary, footer)")
    p.add_argument("bag")
    p.add_argument("output", help="the .mcap file to write (not the bag itself)")
    p.set_defaults(func=_cmd_repair)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="prsm-bag", description="Inspect, export, report on, replay and convert "
                                 "ROS 2 MCAP recordings of the PRSM simulator (or any ROS 2 MCAP with joint states).")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = ap.add_subparsers(dest="command", required=True,
                            metavar="{info,export,report,compare,play,layout,serve,to-rrd,repair}")
    _add_info(sub)
    _add_export(sub)
    report_opts = _add_report(sub)
    _add_compare(sub, report_opts)
    _add_play(sub)
    _add_layout(sub, report_opts)
    add_serve_parser(sub)
    _add_to_rrd(sub, report_opts)
    _add_repair(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BagError as e:
        print(f"prsm-bag {args.command}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:  # stdout closed early (`prsm-bag info BAG | head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as e:
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"prsm-bag {args.command}: error: {where}{e.strerror or e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        interrupt_handled()
        print(f"prsm-bag {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
