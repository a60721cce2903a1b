"""A stand-in for your pose tracker: prints one observation frame per line (JSON), 30 frames a second.

A person's right hand slides the box along the table, from y = 0.32 m to y = 0 m, between t = 1 s and
t = 2 s, and then moves away. Once the box is in front of the cup, the camera cannot see the cup, and
the tracker stops reporting it. Detections carry 3 mm of noise.
"""
import json
import random
import sys

RATE = 30.0          # frames per second
DURATION = 3.5       # seconds
rng = random.Random(0)


def noisy(position, std=0.003):
    return [round(x + rng.gauss(0.0, std), 4) for x in position]


def box_y(t):
    """The box slides from y = 0.32 to y = 0.0 between t = 1 s and t = 2 s."""
    s = min(max(t - 1.0, 0.0), 1.0)
    return 0.32 * (1.0 - s)


for i in range(int(DURATION * RATE)):
    t = round(i / RATE, 4)
    y = box_y(t)
    objects = {"box": {"position": noisy([-0.15, y, 0.751]), "orientation": [0, 0, 0, 1]}}
    if y > 0.2:  # the cup is visible until the box covers it
        objects["cup"] = {"position": noisy([-0.35, 0.0, 0.676]), "orientation": [0, 0, 0, 1]}
    if t < 2.0:  # the hand is against the box's far side, pushing it
        hand = [-0.15, y + 0.17, 0.80]
    else:        # then it moves away
        s = min((t - 2.0) / 0.5, 1.0)
        hand = [-0.15 + 0.35 * s, 0.17 + 0.33 * s, 0.80 + 0.1 * s]
    frame = {"t": t, "objects": objects, "hands": {"human/right": noisy(hand, 0.005)}}
    sys.stdout.write(json.dumps(frame) + "\n")
    sys.stdout.flush()  # a live tracker flushes each frame, so the estimator gets it at once
