"""Free-form queries: relevance comes from a clip's tags, in order, never from its caption text."""

from __future__ import annotations

from retrieval.freeform import DEV_FREEFORM_QUERIES, FREEFORM_QUERIES, FreeformQuery, freeform_relevance


def _row(category: str, tags: list[str], host: list[str]) -> dict[str, object]:
    return {"category": category, "tags": tags, "host_tags": host, "caption": "ignored"}


def test_steps_match_in_order_with_patterns() -> None:
    cut_in = FreeformQuery("a car cuts in from the left", frozenset({"car"}), ("left:*", "host:*"))
    assert cut_in.matches(_row("car", ["left:approach", "host:away"], []))
    assert cut_in.matches(_row("car", ["left:approach", "oncoming:away", "host:constant"], []))  # not adjacent
    assert not cut_in.matches(_row("car", ["host:away", "left:approach"], []))  # wrong order
    assert not cut_in.matches(_row("truck", ["left:approach", "host:away"], []))  # wrong category
    lateral = FreeformQuery("something crossing away on the left", steps=("left*:away",))
    assert lateral.matches(_row("bus", ["left_lateral:away"], [])) and lateral.matches(_row("bus", ["left:away"], []))


def test_host_steps_and_relevance_matrix() -> None:
    stop = FreeformQuery("we brake and stop", host=("decelerating:*", "stationary:*"))
    rows = [_row("car", [], ["decelerating:heading_straight", "stationary:heading_straight"]),
            _row("car", [], ["stationary:heading_straight", "decelerating:heading_straight"]),
            _row("car", [], ["decelerating:steering_left"])]
    assert freeform_relevance([stop], rows).tolist() == [[True, False, False]]
    assert freeform_relevance([stop], []).shape == (1, 0)


def test_the_held_out_set_is_written_in_everyday_words() -> None:
    texts = [q.text for q in FREEFORM_QUERIES]
    assert len(texts) == len(set(texts)) >= 20
    # Unlike the caption templates: no query starts with the host sentence or says "host lane".
    assert not any(t.lower().startswith("the ego vehicle") or "host" in t.lower() for t in texts)
    assert all(q.categories or q.steps or q.host for q in FREEFORM_QUERIES)


def test_the_development_set_is_apart_from_the_held_out_set() -> None:
    dev = [q.text for q in DEV_FREEFORM_QUERIES]
    assert len(dev) == len(set(dev)) >= 30 and not set(dev) & {q.text for q in FREEFORM_QUERIES}
    # Nor the same question in other words: no development query decides relevance as a held-out one does.
    held_out = {(q.categories, q.steps, q.host) for q in FREEFORM_QUERIES}
    assert not [q.text for q in DEV_FREEFORM_QUERIES if (q.categories, q.steps, q.host) in held_out]
    assert not any(t.lower().startswith("the ego vehicle") or "host" in t.lower() for t in dev)
    assert all(q.categories or q.steps or q.host for q in DEV_FREEFORM_QUERIES)
    # A pattern ending in '*' takes the object's own action and context that captioning appends to a step.
    parked = next(q for q in DEV_FREEFORM_QUERIES if q.text == "a parked vehicle on the left")
    assert parked.matches(_row("car", ["left_lateral:constant:parked"], []))
    assert not parked.matches(_row("car", ["left:constant:stopped"], []))
