"""Notifications: the farm tells its operators when it needs them, and only then.

The pure part turns the fleet's live state into events and decides which of them are news:
:mod:`~kybercore.notify.models` (the vocabulary), :mod:`~kybercore.notify.detector`
(transitions of one printer's state), :mod:`~kybercore.notify.noise` (cooldown, pairing of
alerts and recoveries, folding of storms), :mod:`~kybercore.notify.rules` (which channel
gets what, quiet hours) and :mod:`~kybercore.notify.texts` (the messages, en and es).
"""
