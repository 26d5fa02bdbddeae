#!/usr/bin/env python3
"""Times one long command (issue 15's scale runs) and records how its memory and disk grow.

    python bench/slabs/scale.py --log DIR -- COMMAND...

Runs COMMAND with its stdout and stderr in DIR/run.out and DIR/run.err; every 2 s it appends to
DIR/timeline.tsv the elapsed time, the resident memory of the command's whole process tree (so
that a Dask run counts its scheduler, nannies and workers) and the disk space used on the file
system of DIR beyond what was used at the start (spill files, the job folder, the output). At the
end it writes DIR/summary.json: exit status, wall time, peak tree memory and peak extra disk.
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from run import tree_rss_kib  # noqa: E402  (bench/run.py)

PERIOD_S = 2.0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", required=True, help="folder for run.out, run.err, timeline.tsv, summary.json")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    a = ap.parse_args()
    command = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not command:
        ap.error("no command given")
    os.makedirs(a.log, exist_ok=True)
    disk0 = shutil.disk_usage(a.log).used
    peak_rss, peak_disk = 0, 0
    start = time.perf_counter()
    with open(os.path.join(a.log, "run.out"), "w") as out, open(os.path.join(a.log, "run.err"), "w") as err, \
            open(os.path.join(a.log, "timeline.tsv"), "w") as timeline:
        timeline.write("elapsed_s\ttree_rss_mib\textra_disk_gib\n")
        proc = subprocess.Popen(command, stdout=out, stderr=err)
        while proc.poll() is None:
            rss = tree_rss_kib(proc.pid) / 1024
            disk = (shutil.disk_usage(a.log).used - disk0) / 2**30
            peak_rss, peak_disk = max(peak_rss, rss), max(peak_disk, disk)
            timeline.write(f"{time.perf_counter() - start:.1f}\t{rss:.0f}\t{disk:.2f}\n")
            timeline.flush()
            time.sleep(PERIOD_S)
    summary = dict(command=command, exit=proc.returncode, wall_s=round(time.perf_counter() - start, 1),
                   peak_tree_rss_mib=round(peak_rss), peak_extra_disk_gib=round(peak_disk, 2))
    with open(os.path.join(a.log, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(json.dumps(summary))
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
