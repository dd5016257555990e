"""The ground segment on a mission control system (Yamcs): :mod:`.xtce`, the packet definition as XTCE."""
