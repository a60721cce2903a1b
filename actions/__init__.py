"""Actions layer: the FREE / HELD mode model, mode-switch priors and Pick / Place / Release / Push
events."""
from .modes import (EVENT_NAMES, FREE, HELD, MODES, NO_EVENT, PICK, PLACE, PUSH, RELEASE, Mode, ModePriors,
                    is_free, is_held, merge_events, switch_events)
from .events import N_ACTIONS, EventRecord, recent_events, record_event_times
from .push import empty_holds, end_codes, end_holds, lifted, track_holds, unrested_picks, withdraw_picks

__all__ = ["EVENT_NAMES", "FREE", "HELD", "MODES", "NO_EVENT", "PICK", "PLACE", "PUSH", "RELEASE", "Mode",
           "ModePriors", "is_free", "is_held",
           "merge_events", "switch_events", "N_ACTIONS", "EventRecord", "recent_events",
           "record_event_times", "empty_holds", "end_codes", "end_holds", "lifted", "track_holds",
           "unrested_picks", "withdraw_picks"]
