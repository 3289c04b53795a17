"""Help that reaches a person: the spoken request repeated politely, a sound on the dashboard,
notifications to people who are not looking (webhook, ntfy), the answer time recorded."""
