"""The HighD file format (SPEC.md part C): columns and their types, per file.

Per recording ``NN``: ``NN_recordingMeta.csv`` (one row), ``NN_tracksMeta.csv`` (one row per
vehicle), ``NN_tracks.csv`` (one row per vehicle and frame). ``x, y`` are the upper-left corner of
the bounding box in image coordinates (y points down); ``width`` is the box's extent along x (the
vehicle's length), ``height`` along y (its width). Direction 1 moves left (upper lanes, negative x
velocities), direction 2 moves right (lower lanes). Neighbour ids and dhw/thw/ttc are 0 when there
is none; the min* columns of tracksMeta are -1 when undefined.

recordingMeta as published: ``month`` is ``MM.YYYY`` (``09.2017``), ``weekDay`` an English
three-letter day (``Tue``), ``startTime`` ``HH:MM``; ``speedLimit`` is -1 when there is none.
"""
from __future__ import annotations

import re

INT, FLOAT, STR = "int64", "float64", "string"

RECORDING_META = {
    "id": INT, "frameRate": INT, "locationId": INT, "speedLimit": FLOAT, "month": STR, "weekDay": STR,
    "startTime": STR, "duration": FLOAT, "totalDrivenDistance": FLOAT, "totalDrivenTime": FLOAT,
    "numVehicles": INT, "numCars": INT, "numTrucks": INT, "upperLaneMarkings": STR, "lowerLaneMarkings": STR,
}

TRACKS_META = {
    "id": INT, "width": FLOAT, "height": FLOAT, "initialFrame": INT, "finalFrame": INT, "numFrames": INT,
    "class": STR, "drivingDirection": INT, "traveledDistance": FLOAT, "minXVelocity": FLOAT,
    "maxXVelocity": FLOAT, "meanXVelocity": FLOAT, "minDHW": FLOAT, "minTHW": FLOAT, "minTTC": FLOAT,
    "numLaneChanges": INT,
}

TRACKS = {
    "frame": INT, "id": INT, "x": FLOAT, "y": FLOAT, "width": FLOAT, "height": FLOAT,
    "xVelocity": FLOAT, "yVelocity": FLOAT, "xAcceleration": FLOAT, "yAcceleration": FLOAT,
    "frontSightDistance": FLOAT, "backSightDistance": FLOAT, "dhw": FLOAT, "thw": FLOAT, "ttc": FLOAT,
    "precedingXVelocity": FLOAT, "precedingId": INT, "followingId": INT, "leftPrecedingId": INT,
    "leftAlongsideId": INT, "leftFollowingId": INT, "rightPrecedingId": INT, "rightAlongsideId": INT,
    "rightFollowingId": INT, "laneId": INT,
}

NEIGHBOUR_COLUMNS = ("precedingId", "followingId", "leftPrecedingId", "leftAlongsideId", "leftFollowingId",
                     "rightPrecedingId", "rightAlongsideId", "rightFollowingId")

META_FORMATS = {  # published formats of recordingMeta's text columns: (pattern, what it must look like)
    "month": (re.compile(r"^(0[1-9]|1[0-2])\.\d{4}$"), "MM.YYYY, e.g. 09.2017"),
    "weekDay": (re.compile(r"^(Mon|Tue|Wed|Thu|Fri|Sat|Sun)$"), "Mon, Tue, Wed, Thu, Fri, Sat or Sun"),
    "startTime": (re.compile(r"^([01]\d|2[0-3]):[0-5]\d$"), "HH:MM, e.g. 08:38"),
}

FILES = {"recordingMeta": RECORDING_META, "tracksMeta": TRACKS_META, "tracks": TRACKS}


def file_name(recording_id: int, kind: str) -> str:
    return f"{recording_id:02d}_{kind}.csv"


# Plausibility: what a real highway recording must satisfy (the reader refuses the rest, naming the rule;
# ``guardian replay --no-plausibility`` lets an expert go on). One place; the README lists them.
PLAUSIBILITY = {
    "frameRate": (1, 100),        # [Hz] drones record at 25, NGSIM at 10
    "speed": 70.0,                # [m/s] |xVelocity|, |yVelocity| at most this (252 km/h)
    "acceleration": 20.0,         # [m/s^2] |xAcceleration|, |yAcceleration| at most this (2 g)
    "outside_markings": 2.0,      # [m] a box centre lies at most this far beyond its carriageway's outer markings
}
