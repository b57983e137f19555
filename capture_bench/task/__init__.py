"""The task: scenarios, what reset draws for an episode, the capture test (eq. 20), the
physical limit, rewards, the observation, the recorded target side of an episode, and the
accounting of an ended episode that training and evaluation share."""
