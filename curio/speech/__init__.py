"""Speech for the visitors: one engine interface (espeak-ng today) behind a non-blocking queue."""
