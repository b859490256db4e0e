"""English word forms of the compiler's phrases (:mod:`scenarios.lexicon`): a description's words as the
lexicon reads them (:func:`normalize`), plurals of kind words, and the verb forms of turns, lane changes
and motions relative to the ego or another object."""

from __future__ import annotations

import re

_IRREGULAR = {"person": "people", "child": "children", "bus": "buses", "school bus": "school buses",
              "articulated bus": "articulated buses", "pedestrian": "pedestrians", "ego vehicle": "ego vehicles"}


def plural(phrase: str) -> str:
    """The plural of a kind phrase ("bus" → "buses", "school bus" → "school buses")."""
    if phrase in _IRREGULAR:
        return _IRREGULAR[phrase]
    head, _, last = phrase.rpartition(" ")
    if last.endswith(("s", "x", "ch", "sh")):
        last += "es"
    elif last.endswith("y") and last[-2:-1] not in "aeiou":
        last = last[:-1] + "ies"
    else:
        last += "s"
    return f"{head} {last}".strip()


def of_ego(*verbs: str) -> str:
    """Phrases of ``verbs`` with the ego as their object ("approaches us", "moving away from the ego vehicle")."""
    return "|".join(f"{verb} {ego}" for verb in verbs
                    for ego in ("us", "me", "the ego", "the ego vehicle", "the ego car", "our car", "our vehicle"))


def turns(side: str) -> str:
    """Phrases of a turn to ``side`` in every verb form ("turns left", "turned to the left", "takes a left")."""
    return "|".join([*(f"{verb} {side}|{verb} to the {side}" for verb in ("turning", "turns", "turn", "turned")),
                     *(f"{verb} a {side} turn|{verb} a {side}" for verb in ("making", "makes", "make", "made",
                                                                            "taking", "takes", "take", "took")),
                     f"{side} turn|{side} turning"])


def lane_changes(side: str) -> str:
    """Phrases of a lane change to ``side`` in every verb form ("changes lanes to the left", "merged
    right", "moves into the left lane"): "to the left" after the verb is where it goes, not where it is."""
    return "|".join([*(f"{verb} to the {side}|{verb} {side}"
                       for verb in ("changing lanes", "changes lanes", "change lanes", "changed lanes",
                                    "switching lanes", "switches lanes", "switch lanes", "switched lanes",
                                    "merging", "merges", "merge", "merged", "swerving", "swerves", "swerve",
                                    "swerved", "lane change", "lane changing")),
                     *(f"{verb} into the {side} lane|{verb} to the {side} lane"
                       for verb in ("changing", "changes", "change", "changed", "merging", "merges", "merge",
                                    "merged", "moving", "moves", "move", "moved", "switching", "switches")),
                     f"{side} lane change"])


#: "Moving away from" in its verb forms: of the ego, a predicate; of another object, a relation
#: ("accelerating away from" is "accelerating" + "away from").
AWAY_FROM = ("away from", *(f"{verb} away from" for verb in (
    "moving", "moves", "move", "moved", "driving", "drives", "drive", "drove", "walking", "walks", "walk", "walked",
    "riding", "rides", "ride", "rode", "running", "runs", "heading", "heads", "going", "goes")))


def approaches_to(*places: str) -> str:
    """Phrases of approaching ``places`` ("approaches a crosswalk", "nearing the pedestrian crossing")."""
    return "|".join(f"{verb} {the}{place}" for verb in ("approaching", "approaches", "approach", "nearing", "nears",
                                                        "toward", "heading toward", "walking toward", "driving toward")
                    for the in ("", "a ", "the ") for place in places)


#: Phrases of moving across ("walks across", "darting across"): crossing, said with the motion's verb.
ACROSS = "|".join(f"{verb} across" for verb in (
    "walking", "walks", "walk", "walked", "running", "runs", "run", "ran", "jogging", "jogs", "riding", "rides",
    "rode", "cycling", "cycles", "going", "goes", "went", "moving", "moves", "moved", "driving", "drives", "drove",
    "darting", "darts", "darted", "dashing", "dashes", "dashed", "stepping", "steps", "stepped", "hurrying",
    "hurries", "rushing", "rushes", "making its way", "makes its way", "heading", "heads", "coming", "comes",
    "cutting", "cuts", "cut", "swerving", "swerves", "veering", "veers"))

#: Phrases of setting off from a stop ("pulls away from the stop", "accelerating from a standstill").
FROM_A_STOP = "|".join(f"{verb} from {stop}" for verb in (
    "accelerating", "accelerates", "accelerate", "starting", "starts", "start", "pulling away", "pulls away",
    "pull away", "driving away", "drives away", "drive away", "moving off", "moves off", "setting off", "sets off")
                       for stop in ("a stop", "the stop", "its stop", "a standstill", "the standstill", "standstill",
                                    "rest", "a full stop"))


def side_to_side(start: str, end: str) -> str:
    """Phrases of a path from side ``start`` to side ``end`` ("from left to right", "from our left to our right")."""
    return "|".join(f"from {a}{start} to {b}{end}" for a, b in (("", ""), ("the ", "the "), ("our ", "our "),
                                                                  ("the ", ""), ("my ", "my ")))


_SPELLINGS = {"towards": "toward", "colour": "color", "travelling": "traveling", "metres": "meters",
              "pedestrains": "pedestrians", "bicylist": "bicyclist"}


_SUDDEN_STOP = {"stops": "brakes hard and stops", "stop": "brake hard and stop",
                "stopping": "braking hard and stopping", "stopped": "braked hard and stopped"}


def normalize(text: str) -> list[str]:
    """Lower-case words of ``text``: hyphens and slashes split words, numbers and commas stay (a comma
    ends a clause), other punctuation goes."""
    text = text.lower().replace("’", "'")
    text = re.sub(r"(?<=\d),(?=\d{3}\b)", "", text)  # "1,000 m"
    text = re.sub(r"(\d)\s*-\s*(\d)", r"\1 to \2", text)
    text = re.sub(r"\bbetween (\d+(?:\.\d+)?) and (\d)", r"\1 to \2", text)  # "between 10 and 20 km/h"
    text = re.sub(r"(\d)(m|s)\b", r"\1 \2", text)
    text = re.sub(r"[-/]", " ", text)
    # "With no one in front of it", "nobody near us": no object there (elsewhere the words are unused).
    text = re.sub(r"(^|\bwith )(?:no one|noone)\b", r"\1no anyone", text)
    text = re.sub(r"(^|\bwith )no(body|thing)\b", r"\1no any\2", text)
    # "Stops suddenly": brakes hard, then stands; "suddenly brakes": hard.
    text = re.sub(r"\b(?:suddenly|abruptly) (brakes|brake|braking|braked)(?: hard)?\b", r"\1 hard", text)
    text = re.sub(r"\b(?:(?:suddenly|abruptly) (stops|stop|stopping|stopped)|(stops|stop|stopping|stopped) "
                  r"(?:suddenly|abruptly))\b", lambda m: _SUDDEN_STOP[m[1] or m[2]], text)
    # "A truck blocking our lane", "a bus blocking the crosswalk": standing there.
    text = re.sub(r"\b(?:blocking|blocks|block) traffic\b", "stopped in the lane", text)
    text = re.sub(r"\b(?:blocking|blocks|block|blocked) (our|my|the ego|the|a|its) (lane|intersection|junction|road|"
                  r"crosswalk)\b", lambda m: f"stopped {'on' if m[2] == 'crosswalk' else 'in'} {m[1]} {m[2]}", text)
    words = re.findall(r"[a-z]+(?:'[a-z]+)?|\d+(?:\.\d+)?|,", text)  # a comma ends a clause: kept
    return [_SPELLINGS.get(w, w) for w in words]
