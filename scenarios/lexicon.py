"""The words the description compiler knows: phrases for kinds, predicates, relations, counts and the ego.

Each phrase maps to a :class:`Lexeme`; the compiler matches the longest phrase at each position
(:func:`lexemes`). Plurals of kind words are generated, and a few spellings are folded before
matching (:func:`scenarios.word_forms.normalize`), so "bikes", "bicycles", "cyclists" and "bicyclist" all name cyclists,
and "halted", "standing still" and "stopped" the same state.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field

from scenarios.program import Param
from scenarios.word_forms import (
    ACROSS,
    AWAY_FROM,
    FROM_A_STOP,
    approaches_to,
    lane_changes,
    of_ego,
    plural,
    side_to_side,
    turns,
)

#: A relation word the reader turns into one by the other's kind: "braking for a pedestrian" (with it in
#: front) or "for the car ahead" (following it).
SLOWING_FOR = "slowing_for"


@dataclass(frozen=True)
class Lexeme:
    """What a phrase means to the compiler.

    Attributes:
        role: ``kind``, ``pred`` (a predicate on the object), ``rel`` (a relation to the object named
            next), ``ego`` (a relation to the ego), ``with`` / ``between`` (relations whose shape the
            words after them decide), ``side`` (a side, after ``with …``), ``count``, ``unit``,
            ``conj`` (and, or, then, while), ``not``, ``closely`` (tightens the relation before it),
            ``seq`` (a sequence the phrase names: ``drive_off`` stops then moves, ``cut_in`` moves from
            an adjacent lane into the ego's), ``fixed`` (a relation to objects of the kind ``other``
            that the phrase itself names: "at a stop sign", "unattended"), ``mutual`` (a relation to
            one another: "side by side"), ``nearest`` ("closest", "the lead": only the nearest one,
            ``near`` or ``ahead``), or ``skip`` (carries no meaning here).
        name: the kind, predicate, relation, side or conjunction named.
        params: parameters of the predicate or relation.
        reverse: for ``rel``: the relation holds from the named object's point of view ("in front of Y":
            Y has the subject in front), so the compiler asks it of that object and answers the subject.
        count: for ``count``: how many objects at least; for ``fixed``: how many of ``other``.
        other: for ``fixed``: the kind related to.
        negate: for ``pred`` and ``fixed``: the phrase says the opposite ("on the sidewalk": not on the road).
    """

    role: str
    name: str = ""
    params: tuple[Param, ...] = ()
    reverse: bool = False
    count: int = 0
    other: str = ""
    negate: bool = False
    words: tuple[str, ...] = field(default=(), compare=False)


_LEXICON: dict[tuple[str, ...], Lexeme] = {}
#: Kind phrases in the plural ("buses", "people").
PLURAL_KINDS: set[tuple[str, ...]] = set()


def _add(phrases: str, lexeme: Lexeme, plurals: bool = False) -> None:
    for phrase in phrases.split("|"):
        for form in (phrase, plural(phrase)) if plurals else (phrase,):
            _LEXICON[tuple(form.split())] = lexeme
        if plurals:
            PLURAL_KINDS.add(tuple(plural(phrase).split()))


# -- kinds ---------------------------------------------------------------------------------------------
for _phrases, _kind in (
    ("vehicle|auto|automobile|motor vehicle|traffic|active vehicle|road user", "vehicle"),
    ("car|passenger vehicle|passenger car|regular vehicle|sedan|suv|van|pickup|pickup truck", "car"),
    ("truck|lorry|heavy vehicle|large vehicle", "truck"), ("box truck|delivery truck", "box_truck"),
    ("semi truck|semi|truck cab|tractor|truck with trailer|truck cab with trailer", "truck_cab"),
    ("trailer|vehicular trailer", "vehicular_trailer"),
    ("bicycle traffic|bike traffic|cycle traffic", "cyclist"),
    ("bus|city bus|transit bus", "bus"), ("school bus", "school_bus"), ("articulated bus", "articulated_bus"),
    ("pedestrian|person|walker|ped|people|human|jaywalker|child|kid|jogger|official signaler|signaler|flagger|"
     "crossing guard|traffic officer|police officer|construction worker", "pedestrian"),
    ("cyclist|bicyclist|bicycle|bike|biker|bicycle rider|rider on a bicycle", "cyclist"),
    ("wheeled rider|scooter rider|skateboarder|skater|person on a skateboard|person on a scooter|"
     "person riding a skateboard|person riding a scooter", "wheeled_rider"),
    ("motorcycle|motorcyclist|motorbike|motorbike rider|scooter", "motorcycle"),
    ("dog", "dog"), ("animal", "animal"), ("stroller|pram|baby stroller", "stroller"), ("wheelchair", "wheelchair"),
    ("railed vehicle|tram|streetcar|light rail vehicle|light rail train", "railed_vehicle"),
    ("wheeled device|skateboard", "wheeled_device"),
    ("bollard", "bollard"), ("construction cone|traffic cone|cone", "construction_cone"),
    ("construction barrel|barrel", "construction_barrel"),
    ("construction barrier|construction item|construction object|barrier|construction", "construction"),
    ("stop sign", "stop_sign"), ("sign|road sign|traffic sign|yield sign", "sign"),
    ("message board trailer|message board|sign trailer", "message_board_trailer"),
    ("mobile pedestrian sign|mobile pedestrian crossing sign|pedestrian crossing sign",
     "mobile_pedestrian_crossing_sign"),
    ("object|thing|anything|something|agent|actor|anyone|anybody|someone|somebody", "any"),
    ("vulnerable road user|vru", "vulnerable_road_user"),
):
    _add(_phrases, Lexeme("kind", _kind), plurals=True)
_add("ego vehicle|ego|ego car|the av|our car|my car|our vehicle|my vehicle|we|us|self driving car|autonomous vehicle|"
     "our path|my path|the ego's path|the ego vehicle's path", Lexeme("kind", "ego"))  # "crossing our path"


# -- predicates ------------------------------------------------------------------------------------------
for _phrases, _name, _params in (
    ("moving|driving|traveling|travelling|in motion|active|walking|riding|going|heading|moves|"
     "move|drives|walks|rides|navigating|maneuvering|proceeding|passing through", "moving", ()),
    ("about to cross|about to cross the road|about to cross the street|preparing to cross|going to cross|"
     "ready to cross|getting ready to cross|about to step into the road|about to enter the road", "about_to_cross", ()),
    ("stepping off the curb|steps off the curb|step off the curb|stepping into the road|steps into the road|"
     "stepping into the street|steps into the street|stepping onto the road|steps onto the road|entering the road|"
     "enters the road|walking into the road|walks into the road|into the road|into the street|onto the road|"
     "onto the street|out into the road|out into the street|into traffic", "crossing_road", ()),
    # Not "backed up": traffic that is backed up queues, it does not reverse.
    ("reversing|reverses|reverse|reversed|in reverse|backing up|backs up|back up|backing out|backs out|"
     "backing|rolling back|rolls back|rolled back|rolling backwards|rolls backwards|moving backwards|moves backwards|"
     "driving backwards|drives backwards|going backwards|goes backwards|backwards|backward", "reversing", ()),
    ("waiting to cross|waits to cross|wait to cross|waiting to cross the road|waiting to cross the street",
     "stopped", ()),  # not crossing yet: "cross" alone is the crossing relation
    ("pulling over|pulls over|pulled over|pulling into a stop|pulls into a stop|pulling up|pulls up|has stopped|"
     "have stopped|had stopped", "stopped", ()),
    ("stopped|halted|standing still|stopping|waiting|idling|stationary vehicle|at a standstill|"
     "stands|stand|standing|stop|stops|waits|wait|comes to a stop|come to a stop", "stopped", ()),
    ("stationary|hasn't moved|has not moved|never moves|never move|never moved|unmoving|static", "stationary", ()),
    ("parked|parking", "parked", ()),
    ("accelerating|speeding up|gaining speed|accelerates|accelerate|speeds up|speed up|sped up|picks up speed|"
     "picking up speed", "accelerating", ()),
    ("accelerates quickly|accelerating quickly|accelerates hard|accelerating hard|accelerates rapidly|"
     "accelerating rapidly|hard acceleration|rapid acceleration|accelerate hard|accelerate quickly|"
     "accelerated hard|accelerated quickly|accelerate rapidly", "accelerating", (("min_mps2", 2.0),)),
    ("braking|slowing down|decelerating|slowing|brakes|brake|slow down|slows down|slowed down|decelerates|"
     "decelerate", "braking", ()),
    ("hard braking|braking hard|slamming on the brakes|emergency braking|brakes hard|brake hard|braked hard|"
     "brakes sharply|braking sharply|brakes suddenly|braking suddenly|sudden braking|slams on the brakes|"
     "slams on its brakes", "braking", (("min_mps2", 3.0),)),
    ("turning|making a turn|turns|turn|u turn|u turning|u turns|wide turn|making a wide turn|makes a wide turn|"
     + "|".join(
        f"{verb} a u turn" for verb in ("making", "makes", "make", "doing", "does", "do", "taking", "takes")),
     "turning", ()),
    (turns("left"), "turning", (("direction", "left"),)),
    (turns("right"), "turning", (("direction", "right"),)),
    ("changing lanes|lane change|lane changing|changes lanes|change lanes|switching lanes|merging|merges|"
     "swerving|weaving", "changing_lanes", ()),
    (lane_changes("left"), "changing_lanes", (("direction", "left"),)),
    (lane_changes("right"), "changing_lanes", (("direction", "right"),)),
    ("at crawling speed|crawling|creeping|moving slowly|slow moving|slow|slowly", "slow", ()),
    # Running is a pace, not just motion: at or above a pedestrian's fast speed (a vehicle that runs moves:
    # scenarios.parser.RUNS).
    ("fast|speeding|at high speed|quickly|running fast|very fast|running|runs|jogging|jogs|sprinting|sprints|"
     "darting|darts|dashing|dashes", "fast", ()),
    ("at intersection|at an intersection|at the intersection|on intersection|on an intersection|in intersection|"
     "in an intersection|in the intersection|through intersection|through the intersection|at a junction|"
     "in the junction|at the junction|in the middle of the intersection|in the middle of an intersection|"
     "in the middle of the junction", "at_intersection", ()),
    ("near intersection|near an intersection|near the intersection|approaching intersection|"
     "approaching an intersection|approaching the intersection", "near_intersection", ()),
    ("on crosswalk|on a crosswalk|on the crosswalk|in crosswalk|in the crosswalk|on pedestrian crossing|"
     "on a pedestrian crossing|on the pedestrian crossing|using designated crossing|using the crosswalk|"
     "using a crosswalk|on zebra crossing", "on_crosswalk", ()),
    ("at crosswalk|at a crosswalk|at the crosswalk|at a pedestrian crossing|at pedestrian crossing|"
     "at the pedestrian crossing|near a crosswalk|near the crosswalk|next to the crosswalk|by the crosswalk|"
     "beside the crosswalk", "at_crosswalk", ()),
    ("in bike lane|in a bike lane|in the bike lane|on bike lane|in bicycle lane|in the bicycle lane", "in_bike_lane",
     ()),
    ("in bus lane|in a bus lane|in the bus lane", "in_bus_lane", ()),
    ("on road|on the road|in the road|in road|on the street|in the street|in drivable area|in the drivable area|"
     "in the middle of the road|in the middle of the street", "on_road", ()),
    ("blocked|stuck|held up|queued|queuing|in a queue", "blocked", ()),
    ("jaywalking|jaywalks|jaywalk|crossing the road outside a crosswalk|at a non crosswalk location|"
     "at a non crosswalk|non crosswalk|outside a crosswalk|outside the crosswalk|outside of a crosswalk|"
     "away from a crosswalk|away from the crosswalk|mid block|midblock|in the middle of the block",
     "jaywalking", ()),
    ("at stop|at a stop|at its stop", "stopped", ()),
    ("in vehicle lane|in a vehicle lane|in the vehicle lane|in a traffic lane|in the traffic lane|in traffic|"
     "in the lane|in a lane|in a travel lane|in the travel lane|in the driving lane|in a driving lane",
     "in_vehicle_lane", ()),
    ("from bike lane|from the bike lane|from a bike lane|out of the bike lane|through bike lane|through the bike lane|"
     "into the bike lane|into a bike lane|across the bike lane", "in_bike_lane", ()),
    ("intersection|an intersection|the intersection|junction|a junction|" + approaches_to("intersection", "junction"),
     "near_intersection", ()),
    (approaches_to("crosswalk", "pedestrian crossing"), "approaching_crosswalk", ()),
    (of_ego("approaching", "approaches", "approach", "approached", "getting closer to", "gets closer to",
             "coming closer to", "comes closer to", "closing in on", "closes in on", "toward", "comes back toward",
             "coming toward", "comes toward"), "approaching_ego", ()),
    (of_ego(*AWAY_FROM, "pulling away from", "pulls away from", "pulled away from", "pull away from"),
     "moving_away_from_ego", ()),
    ("oncoming|coming toward us|coming towards us|comes toward us|comes towards us|come toward us|"
     "come towards us|in the oncoming lane|on the other side of the road",
     "ego_lane", (("lane", "oncoming"),)),
    ("in same lane|in the same lane|in my lane|in our lane|in the ego lane|in ego lane|in the same lane as us|"
     "in the same lane as the ego vehicle|in the same lane as the ego|in front of us in our lane", "ego_lane",
     (("lane", "host"),)),
    ("in the left lane|in the lane to our left|in the lane on our left|in the left adjacent lane|"
     "in the lane to the left of us|in the lane left of us|in the lane to the left of the ego vehicle", "ego_lane",
     (("lane", "left"),)),
    ("in the adjacent lane|in an adjacent lane|in the lane next to us|in the next lane|in the lane beside us|"
     "in the neighboring lane|in the next lane over|in a lane next to ours|in the lane next to ours", "ego_lane",
     (("lane", "adjacent"),)),
    ("in the right lane|in the lane to our right|in the lane on our right|in the right adjacent lane|"
     "in the lane to the right of us|in the lane right of us|in the lane to the right of the ego vehicle", "ego_lane",
     (("lane", "right"),)),
    ("getting closer|coming closer|closing in|approaching|approaches|approach|gets closer|comes closer",
     "approaching_ego", ()),
    ("moving away|driving away|leaving|moves away|move away|moved away|drives away|drive away|drove away|"
     "walking away|walks away|walk away|walked away|riding away|rides away|ride away|rode away|going away|"
     "goes away|heading away|heads away", "moving_away_from_ego", ()),
):
    _add(_phrases, Lexeme("pred", _name, _params))

# -- relations to an object named next ------------------------------------------------------------------
for _phrases, _rel, _rparams, _reverse in (
    ("near|close to|next to|around|in close proximity to|in proximity to|alongside|by|adjacent to",
     "near", (), False),
    ("very close to|very near|really close to|right next to|right beside", "near", (("within_m", 3.0),), False),
    ("following|behind|tailing|trailing|driving behind|following behind|follow|follows", "following", (), False),
    ("following closely|closely following|following closely behind|closely behind|tailgating|too closely behind|"
     "close behind|right behind",
     "following", (("within_m", 10.0),), False),
    ("being followed by|followed by", "following", (), True),
    ("followed closely by|closely followed by|being followed closely by", "following", (("within_m", 10.0),), True),
    ("in front of|ahead of|before|in front|directly in front of|straight ahead of|directly ahead of|right ahead of",
     "direction", (("side", "front"),), True),
    ("to either side of|on either side of|to both sides of|on both sides of|either side of|beside|alongside of",
     "direction", (("side", "beside"),), True),
    ("to the front left of|front left of|to the front-left of", "direction", (("side", "front_left"),), True),
    ("to the front right of|front right of", "direction", (("side", "front_right"),), True),
    ("to the back left of|to the rear left of|back left of|behind and to the left of", "direction",
     (("side", "back_left"),), True),
    ("to the back right of|to the rear right of|back right of|behind and to the right of", "direction",
     (("side", "back_right"),), True),
    ("facing away from|turned away from|with its back to", "direction", (("side", "behind"),), False),
    ("to the left of|left of|on the left of|on the left side of|along the left side of", "direction",
     (("side", "left"),), True),
    ("to the right of|right of|on the right of|on the right side of|along the right side of", "direction",
     (("side", "right"),), True),
    ("directly to the left of", "direction", (("side", "left"), ("lateral_m", 2.0)), True),
    ("directly to the right of", "direction", (("side", "right"), ("lateral_m", 2.0)), True),
    ("in the same lane as|in same lane as|sharing a lane with|sharing lane with|in the lane of|in its lane with|"
     "sharing the lane with", "same_lane", (), False),
    ("being crossed by|crossed by", "crossed_by", (), False),
    # "Stopped for" with no object after it is a duration: "a car stopped for 10 s".
    ("yielding to|yields to|yield to|yielded to|giving way to|gives way to|give way to|waiting for|waits for|"
     "wait for|waiting on|yielding|yields|yield|yielded|giving way|gives way|give way|stopping for|stops for|"
     "stop for|stopped for|halting for|halts for", "yielding_to", (), False),
    # Read by scenarios.relating.RelationReader.slowing_for: braking with the other in front, or behind it.
    ("braking for|brakes for|braked for|brake for|slowing down for|slows down for|slowed down for|"
     "slow down for|slowing for|slows for|slowed for|decelerating for|decelerates for", SLOWING_FOR, (), False),
    ("braking hard for|brakes hard for|brake hard for|braked hard for|slamming on the brakes for|"
     "slams on the brakes for|slammed on the brakes for", SLOWING_FOR, (("min_mps2", 3.0),), False),
    ("crossing|crossing in front of|crossing the path of|crossing in front|cutting in front of|crosses|cross|"
     "crossing paths with|crossing path of|across the path of|across in front of|" + ACROSS, "crossed_by", (), True),
    ("being passed by|passed by|being overtaken by|overtaken by|being overtaken|overtaken|being passed", "passed_by",
     (), False),
    ("past the right side of|past right side of|past the right of", "passed_by", (("side", "right"),), True),
    ("passed on the right by|overtaken on the right by|being passed on the right by|being overtaken on the right by",
     "passed_by", (("side", "right"),), False),
    ("passed on the left by|overtaken on the left by|being passed on the left by|being overtaken on the left by",
     "passed_by", (("side", "left"),), False),
    ("past the left side of|past left side of|past the left of", "passed_by", (("side", "left"),), True),
    ("at", "near", (("within_m", 5.0),), False),
    ("passing|overtaking|passes|overtakes|pass|overtake|overtook", "passed_by", (), True),
    # Going past, unlike overtaking, is either way (an oncoming car drives past us); "past" alone, so that
    # "walking past the right side of" is "walking" + "past the right side of".
    ("past|straight past|right past|passing by|drive past|drives past|driving past|drove past|goes past|"
     "going past|go past|went past|drive straight past|drives straight past|driving straight past|passes by|"
     "pass by|" + "|".join(
        f"{verb} by" for verb in ("drive", "drives", "driving", "walk", "walks", "walking", "ride", "rides",
                                  "riding", "goes", "going", "go")), "passed_by", (("way", "either"),), True),
    ("facing|facing toward|facing towards|looking at|facing at", "facing", (), False),
    ("|".join(AWAY_FROM), "heading_away_from", (), False),
    ("heading toward|heading towards|moving toward|moving towards|approaching|driving toward|driving towards|"
     "accelerating toward|accelerating towards|walking toward|walking towards|toward|coming toward|comes toward",
     "heading_toward", (), False),
    ("traveling in the opposite direction as|going the opposite way to|in the opposite direction of|"
     "traveling opposite to|opposite to|against|the opposite way to|the opposite way from|the opposite way as|"
     "in the opposite direction to|in the opposite direction from",
     "heading", (("way", "opposite"),), False),
    ("traveling in the same direction as|in the same direction as|going the same way as|the same way as|parallel to",
     "heading", (("way", "same"),), False),
):
    _add(_phrases, Lexeme("rel", _rel, _rparams, _reverse))

# -- relations to the ego (no object named) --------------------------------------------------------------
for _phrases, _side in (("ahead|in front|ahead of us|in front of us|straight ahead", "front"),
                        ("behind us|behind the ego|behind the ego vehicle|behind the ego car|in the rear", "behind"),
                        ("to our left|on our left|to the left of us", "left"),
                        ("to our right|on our right|to the right of us", "right")):
    _add(_phrases, Lexeme("ego", "direction", (("side", _side),), reverse=True))
# "Directly" ahead or behind: within the ego's lane band (the chain of "two cars ahead" uses the same band).
_add("directly ahead of us|directly in front of us|right in front of us|straight ahead of us",
     Lexeme("ego", "direction", (("side", "front"), ("lateral_m", 1.5)), reverse=True))
_add("directly behind us|right behind us", Lexeme("ego", "direction", (("side", "behind"), ("lateral_m", 1.5)), True))

# -- sides after "with …" -----------------------------------------------------------------------------------
for _phrases, _side in (
    ("to its left|on its left|on the left|to the left|on left|to left|from the left|from left|on its left side|"
     "to their left|on their left", "left"),
    ("to its right|on its right|on the right|to the right|on right|to right|from the right|from right|"
     "on its right side|to their right|on their right", "right"),
    ("in front of it|ahead of it|ahead|in front|in front of them|ahead of them|in its path", "front"),
    ("behind it|behind them|behind", "behind"),
    ("on either side|on both sides|on each side|on either side of it|on both sides of it|beside it", "beside"),
    ("in its lane|in their lane|in its own lane|sharing its lane", "same_lane"),
    ("nearby|close by|around it|near it|next to it", "near"),
):
    _add(_phrases, Lexeme("side", _side))

# -- counts, units, conjunctions, negation, filler -----------------------------------------------------------
for _phrases, _n in (("multiple|several|many|more than one|a couple of|couple of|numerous", 2),
                     ("two|pair of|a pair of|both", 2), ("three", 3), ("four", 4), ("five", 5)):
    _add(_phrases, Lexeme("count", count=_n))
_add("group of|a group of|crowd of|a crowd of|groups of|bunch of|group|crowd|groups", Lexeme("count", "group", count=3))
_add("with|having|has|carrying|towing|accompanied by|pushing", Lexeme("with"))
_add("has been|have been|had been|that has been|which has been|that have been|who has been", Lexeme("skip"))
for _phrases, _lexeme in (
    ("at stop sign|at a stop sign|at the stop sign|near a stop sign|near stop sign",
     Lexeme("fixed", "near", (("within_m", 15.0),), other="stop_sign", count=1)),
    ("in dense traffic|in heavy traffic|in a traffic jam|in traffic jam|in congested traffic",
     Lexeme("fixed", "near", (("within_m", 25.0),), other="vehicle", count=5)),
    ("isolated|alone|on its own|by itself", Lexeme("fixed", "near", (("within_m", 15.0),), other="any", count=1,
                                                     negate=True)),
    ("unattended|unaccompanied|without an owner|without a person", Lexeme("fixed", "near", (("within_m", 5.0),),
                                                                         other="pedestrian", count=1, negate=True)),
):
    _add(_phrases, _lexeme)
# Without an object, "in the opposite direction" is the ego's ("traveling in the opposite direction as X" is X's).
_add("in the opposite direction|in opposite direction|the other way",
     Lexeme("fixed", "heading", (("way", "opposite"),), other="ego", count=1))
_add("in the same direction|in same direction",
     Lexeme("fixed", "heading", (("way", "same"),), other="ego", count=1))
# Straight on: not turning (whether it moves is said apart: "driving straight").
_add("straight|go straight|goes straight|going straight|went straight", Lexeme("pred", "turning", negate=True))
# Not moving: stopped for a moment or parked for the whole log (``stopped`` alone leaves parked ones out).
_add("not moving|isn't moving|is not moving|are not moving|aren't moving", Lexeme("pred", "moving", negate=True))
_add("closely|too closely|too close|tightly", Lexeme("closely"))
# Of one another: the objects of the clause relate to others of their kind (or, "X and Y …", to each other).
_add("side by side|next to each other|alongside each other|beside each other|next to one another",
     Lexeme("mutual", "direction", (("side", "beside"), ("within_m", 3.0), ("lateral_m", 1.0))))
_add("near each other|close to each other|near one another|close to one another|close together",
     Lexeme("mutual", "near", (("within_m", 5.0),)))
_add("closest|nearest|closest one|nearest one", Lexeme("nearest", "near"))
_add("lead|leading|leads|the first", Lexeme("nearest", "ahead"))
_add("drives off|drive off|driving off|drove off|pulls away|pull away|pulling away|pulled away|starts moving|"
     "start moving|starting to move|started moving|takes off|taking off|took off|sets off|setting off|"
     "starts to move|started to move|"
     "accelerates quickly from a stop|accelerating quickly from a stop|accelerates hard from a stop|"
     "pulls out|pulling out|pulling out of a parking spot|pulls out of a parking spot|"
     "pulling out of a parking space|pulls out of a parking space|" + FROM_A_STOP, Lexeme("seq", "drive_off"))
# From one side of us to the other: "crossing from left to right" (where it starts, then where it ends).
_add(side_to_side("left", "right"), Lexeme("seq", "side_to_side", (("side", "left"),)))
_add(side_to_side("right", "left"), Lexeme("seq", "side_to_side", (("side", "right"),)))
_add("cuts into my lane|cuts into our lane|cutting into my lane|cutting into our lane|cuts in|cutting in|cut in|"
     "cuts in front of us|cutting in front of us|cutting us off|cuts us off|cut us off|cut off|merges into my lane|"
     "merges into our lane|merging into our lane|"
     "moves into the ego lane|moves into our lane|moves into my lane|moving into our lane|moving into the ego lane|"
     "changes into our lane|changes into my lane|moves into the host lane|moving into the host lane|"
     "into the host lane|into the ego lane|into our lane|into my lane|entering our lane|enters our lane|"
     "entering my lane|enters my lane|entering the ego lane|enters the ego lane", Lexeme("seq", "cut_in"))
_add("leaving our lane|leaves our lane|leaving my lane|leaves my lane|leaving the ego lane|exiting our lane|"
     "exits our lane|moving out of our lane|moves out of our lane|changing out of our lane|cuts out|cutting out",
     Lexeme("seq", "cut_out"))
_add("on sidewalk|on the sidewalk|on a sidewalk|off the road|not on the road|off road", Lexeme("pred", "on_road",
                                                                                               negate=True))
_add("during daylight|in daylight|during the day|in the daytime|on a clear day|during the daytime",
     Lexeme("pred", "appearance", (("time_of_day", "day"),)))
_add("at night|during the night|at nighttime|in the dark", Lexeme("pred", "appearance", (("time_of_day", "night"),)))
_add("at dusk|during dusk|at dawn|at sunset|at twilight", Lexeme("pred", "appearance", (("time_of_day", "dusk"),)))
for _phrases, _weather in (("during rain|in the rain|in rain|while raining|when it rains|on a rainy day", "rain"),
                           ("during snow|in the snow|in snow|while snowing|on a snowy day", "snow"),
                           ("in fog|in the fog|during fog|on a foggy day", "fog")):
    _add(_phrases, Lexeme("pred", "appearance", (("weather", _weather),)))
_add("between", Lexeme("between"))
_add("meters|meter|metres|metre|m", Lexeme("unit", "m"))
_add("feet|ft", Lexeme("unit", "ft"))  # read in metres (scenarios.quantities.FOOT_M)
_add("on foot", Lexeme("skip"))  # "a person on foot": a pedestrian already
# Speeds, in metres per second: "m/s" and "km/h" arrive as "m s" and "km h" (normalize splits at "/").
_add("m s|meters per second|meter per second|metres per second|mps", Lexeme("unit", "mps"))
_add("km h|kmh|kph|km per hour|kilometers per hour|kilometres per hour", Lexeme("unit", "kmh"))
_add("mph|miles per hour|mile per hour", Lexeme("unit", "mph"))
_add("faster than|quicker than|slower than|farther than|further than|closer than|nearer than|above|over|exceeding|"
     "below|under|about|approximately",
     Lexeme("skip"))
_add("seconds|second|secs|sec|s", Lexeme("unit", "s"))
for _phrases, _name in (("and|as well as|also|while also", "and"), ("or|either", "or"),
                        ("except|except for|other than|excluding|but not|apart from|besides", "except"),
                        ("then|and then|after that|afterwards|before", "then"), ("after|once", "after"),
                        ("while|when|during|as|whilst", "while")):
    _add(_phrases, Lexeme("conj", _name))
_add("not|no|without|isn't|aren't|doesn't|neither|nor|does not|do not|did not|didn't|don't|fails to|fail to|"
     "failing to|failed to", Lexeme("not"))
# Named as not understood: a place the map does not hold ("at a bus stop" asks nothing of buses), traffic
# lights ("running a red light" asks nothing of speed), and "across from us" (where it is, not a crossing).
_add("|".join(f"{verb} {the}red light" for verb in ("running", "runs", "ran", "run") for the in ("a ", "the ", ""))
     + "|red light|red lights|traffic light|traffic lights|on red|on a red|at a red light|at the red light",
     Lexeme("unknown", "traffic light"))
_add("across from|across the street from|across the road from", Lexeme("unknown", "across from"))
_add("at a bus stop|at the bus stop|near a bus stop|near the bus stop|by a bus stop|by the bus stop|bus stop",
     Lexeme("unknown", "bus stop"))
_add("|".join(f"{via} {the} {place}" for via in ("out of", "of", "from", "into") for the in ("a", "the")
              for place in ("parking spot", "parking space", "driveway", "parking lot")),
     Lexeme("unknown", "parking spot"))
_add("within|at least|at most|less than|more than|up to|from|away|for|directly|another|other|each|any|"
     "some|its|their|the|a|an|that|which|who|is|are|being|of|it|they|them|there|in|on|to|one|ones|those|these|same|lane|path|"
     "side|too|road|street|zone|area|i|see|find|show|me|all|where|together|here|now|just|first|,",
     Lexeme("skip"))

_MAX_PHRASE = max(len(k) for k in _LEXICON)
_VERB_WORDS = {k[0] for k, v in _LEXICON.items() if v.role in ("pred", "seq", "rel")}
#: Verbs in their plain form ("wait", "brake", "cross", "slow down"): present tense for a plural subject.
PLAIN_VERBS = frozenset(w for w in _VERB_WORDS - {"backward", "close"}  # "backwards", "close to": no verbs
                        if not w.endswith("ing") and {w + "s", w + "es"} & _VERB_WORDS)


def lexemes(words: list[str]) -> list[Lexeme]:
    """The longest-matching lexeme at each position (``number`` lexemes for numbers; ``unknown`` ones for
    words the lexicon lacks), each with the words it covers."""
    out: list[Lexeme] = []
    i = 0
    while i < len(words):
        if re.fullmatch(r"\d+(?:\.\d+)?", words[i]) or (words[i] == "away" and out and (
                out[-1].role == "unit" or out[-1].words == ("far",))):  # "20 m away from", "far away": no motion
            out.append(Lexeme("number", words[i], words=(words[i],)) if words[i] != "away" else
                       Lexeme("skip", words=(words[i],)))
            i += 1
            continue
        for size in range(min(_MAX_PHRASE, len(words) - i), 0, -1):
            found = _LEXICON.get(tuple(words[i:i + size]))
            if found is not None:
                out.append(dataclasses.replace(found, words=tuple(words[i:i + size])))
                i += size
                break
        else:
            out.append(Lexeme("unknown", words[i], words=(words[i],)))
            i += 1
    return out


def known_phrases() -> list[str]:
    """Every phrase of the lexicon that means something."""
    return sorted(" ".join(k) for k, v in _LEXICON.items() if v.role not in ("skip", "unit"))
