"""The Taiji-2 ground segment: what runs on the ground of the onboard/ground data flow (docs/link.md).

- :mod:`.nodes.ground_receiver`: telemetry in from the space link, reception records, /diagnostics
- :mod:`.nodes.command_planner`: the maneuver as time-tagged tables uplinked in the contacts
- :mod:`.reception`: ground reception of a live packet stream (per APID, in sequence order, gaps declared)
- :mod:`.raw_packets`: packet files and directories loaded as raw-data records
- :mod:`.mcs.xtce`: the packet definition as an XTCE database for a mission control system (Yamcs)
"""
