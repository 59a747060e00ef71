"""Merge the per-(task, strategy) thesis-preset runs of .exp/gpu_lfd_thesis.sh into one folder."""
import csv, glob, json, os, shutil, sys
sys.path.insert(0, ".")
from scripts.lfd_franka import plot_errors
src, out = sys.argv[1], sys.argv[2]
os.makedirs(os.path.join(out, "logs"), exist_ok=True)
tasks, rows, settings = {}, [], {}
for task in ("door_reaching", "drawer_closing"):
    for s in ("cspace", "independent", "joint", "single_link"):
        d = os.path.join(src, task, s)
        m = json.load(open(os.path.join(d, "metrics.json")))
        tasks.setdefault(task, {})[s] = m["tasks"][task][s]
        settings[f"{task}/{s}"] = m["settings"]
        rows += list(csv.DictReader(open(os.path.join(d, "table.csv"))))
        shutil.copy(os.path.join(d, "run.log"), os.path.join(out, "logs", f"{task}_{s}.log"))
json.dump({"settings": settings, "tasks": tasks}, open(os.path.join(out, "metrics.json"), "w"), indent=1)
with open(os.path.join(out, "table.csv"), "w", newline="") as fh:
    w = csv.DictWriter(fh, fieldnames=list(rows[0])); w.writeheader(); w.writerows(rows)
plot_errors(os.path.join(out, "lfd_franka_reference_errors.png"), tasks)
for r in rows:
    print(r["task"], r["strategy"], r["mean_position_error_cm"], r["std_cm"], r["success_rate"], r["task_success_rate"], r["median_corridor_excursion_cm"], r["success_rate_obstacle"], r["success_rate_no_posture"], r["colliding_rollouts"], r["min_clearance_cm"], r["train_seconds"])
