"""The link experiment's monitor takes what queued while it waited, in one go, and stops when nothing is left."""

from taiji2_apps.cli.experiment_link import spin_for


class _QueuedExecutor:
    """spin_once runs one queued callback (as rclpy's), counting the messages taken; a spin that finds a
    callback other than a message (a timer) takes nothing."""

    def __init__(self, items):
        self.items = list(items)
        self.taken = 0
        self.spins = 0

    def spin_once(self, timeout_sec=None):
        self.spins += 1
        if self.items:
            if self.items.pop(0) == "message":
                self.taken += 1


def test_every_queued_message_is_taken_in_one_call():
    executor = _QueuedExecutor(["message"] * 250)
    spin_for(executor, 0.0, lambda: executor.taken)
    assert executor.taken == 250 and executor.spins == 251


def test_a_spin_that_takes_nothing_ends_the_call_and_the_rest_waits_for_the_next():
    executor = _QueuedExecutor(["message", "message", "timer", "message"])
    spin_for(executor, 0.0, lambda: executor.taken)
    assert executor.taken == 2 and executor.items == ["message"]
    spin_for(executor, 0.0, lambda: executor.taken)
    assert executor.taken == 3 and not executor.items
