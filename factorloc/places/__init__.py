"""Places: a map of the places a robot knows, choosing among them, and place recognition.

Above :mod:`factorloc.pipeline` in the layering (types → estimators → gating → fusion → pipeline → places):

- :mod:`~factorloc.places.placemap`: :class:`Place`, :class:`PlaceMap` (built from a scenario or one by one,
  saved as a scenario without queries);
- :mod:`~factorloc.places.choose`: the places whose view can overlap a query, given a reliable pose hypothesis;
- :mod:`~factorloc.places.recognition`: place recognition without one (D2, Scan Context, scan-to-submap matching,
  panorama Fourier signature);
- :mod:`~factorloc.places.verify`: the retrieved places verified by the ICP step without a hypothesis, re-ranked;
- :mod:`~factorloc.places.multi`: the hierarchy against several places, fused on one pose (:class:`PlaceLocalization`).
"""

from factorloc.places.choose import ChoiceConfig, places_in_view
from factorloc.places.multi import MultiPlaceLocalizer, PlaceLocalization, PlaceRun, place_factor, split_step_name
from factorloc.places.placemap import PLACE_COVARIANCE_KEY, Place, PlaceMap
from factorloc.places.recognition import (
    PlaceCandidate,
    PlaceRecognizer,
    RecognitionConfig,
    local_submap,
    neighbour_submaps,
    panorama_signature,
    scan_context,
    scan_context_distance,
    scan_context_key,
    shape_distribution,
    submap_match,
)
from factorloc.places.tracker import Tracker, TrackerConfig, TrackResult, TrackState, seed_of_prediction
from factorloc.places.verify import VERIFY_SHORTLIST, PlaceVerifier, VerifiedPlace

__all__ = [
    "PLACE_COVARIANCE_KEY",
    "VERIFY_SHORTLIST",
    "ChoiceConfig",
    "MultiPlaceLocalizer",
    "Place",
    "PlaceCandidate",
    "PlaceLocalization",
    "PlaceMap",
    "PlaceRecognizer",
    "PlaceRun",
    "PlaceVerifier",
    "RecognitionConfig",
    "TrackResult",
    "TrackState",
    "Tracker",
    "VerifiedPlace",
    "TrackerConfig",
    "local_submap",
    "neighbour_submaps",
    "panorama_signature",
    "place_factor",
    "places_in_view",
    "scan_context",
    "scan_context_distance",
    "scan_context_key",
    "seed_of_prediction",
    "shape_distribution",
    "split_step_name",
    "submap_match",
]
