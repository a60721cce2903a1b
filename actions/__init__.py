"""Actions layer: the FREE / HELD mode model, mode-switch priors and Pick / Place / Release events."""
from .modes import (EVENT_NAMES, FREE, HELD, NO_EVENT, PICK, PLACE, RELEASE, ModePriors,
                    merge_events, switch_events)
from .events import EventRecord, recent_events, record_event_times

__all__ = ["EVENT_NAMES", "FREE", "HELD", "NO_EVENT", "PICK", "PLACE", "RELEASE", "ModePriors",
           "merge_events", "switch_events", "EventRecord", "recent_events",
           "record_event_times"]
