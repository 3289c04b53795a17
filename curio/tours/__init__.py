"""Tours as a product: named tours of stops, their schedules, the scheduler and the service
the dashboard and the kiosk call (see docs/tours.md)."""
