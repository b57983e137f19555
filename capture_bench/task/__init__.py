"""The task: scenarios, what reset draws for an episode, the capture test (eq. 20), the
physical limit, rewards, the observation and the recorded target side of an episode."""
