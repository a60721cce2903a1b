"""Print what the estimator believes at the end of a run: one line per object, the relations, the
events of the last second."""
import json
import sys

path = sys.argv[1] if len(sys.argv) > 1 else "estimates.jsonl"
with open(path) as f:
    last = [json.loads(line) for line in f][-1]

print(f"t = {last['t']:.2f} s, effective sample size {last['ess']:.1f}")
for name, obj in last["objects"].items():
    if not obj["hypotheses"]:  # a static object (the table): it is where the scene says
        continue
    x, y, z = obj["position"]
    std = [obj["position_cov"][i][i] ** 0.5 * 100 for i in range(3)]
    best = obj["hypotheses"][0]
    print(f"{name}: at ({x:.3f}, {y:.3f}, {z:.3f}) m, std ({std[0]:.1f}, {std[1]:.1f}, {std[2]:.1f}) cm, "
          f"perceived {obj['perceived']}, P(held) {obj['p_held']:.2f}, "
          f"most probable: {best['relation']} {best.get('support')} (p {best['p']:.2f})")
for rel in last["relations"]:
    print(f"relation: {rel['subject']} {rel['predicate']} {rel['object']}, p {rel['p']:.2f}")
for event in last["events"]:
    print(f"event: {event['action']} {event['subject']} at t = {event['t']:.2f} s, p {event['p']:.2f}")
