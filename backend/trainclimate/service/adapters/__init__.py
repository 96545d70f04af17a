"""Adapters: where telemetry comes from and setpoints go, besides the API's live feed.

- :mod:`.demo` — the demo fleet (``trainclimate serve --fleet demo``): simulated trains in the
  service's process, on an accelerated clock, writing their telemetry to the store and driving
  the scheduler's ticks;
- :mod:`.mqtt` — the MQTT live feed (``serve --mqtt``): the broker, the topics, the service's
  bridge;
- :mod:`.dynsec` — each gateway token's own broker client (``serve --mqtt-dynsec``), through
  Mosquitto's dynamic security plugin;
- :mod:`.gateway` — the onboard gateway emulator (``trainclimate gateway``): a separate process
  that speaks only the live feed's protocols, HTTP or MQTT.

They build on the store and the scheduler; nothing in the store, the scheduler or the API imports
them (the app starts the demo fleet, the MQTT feed and the broker clients, the CLI the gateway).
"""

#: The MQTT topics' prefix (:mod:`.mqtt`; the settings' default, ``mqtt_prefix``). Here, not in
#: :mod:`.mqtt`, so that the settings read it without importing the feed, which reads them.
MQTT_PREFIX = "trainclimate/v1"
