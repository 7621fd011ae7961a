"""The two load states of every pose, in the order a campaign measures them: the one spelling of
the word that the scenario's timeline, the tracker, the campaign, the log and the readings files
(docs/contract.md: ``state`` is ``unloaded`` or ``loaded``) all use."""

STATES = ("unloaded", "loaded")
