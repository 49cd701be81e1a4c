"""What a simulated vehicle is, as one object, and building it: the vehicle's plug-in point.

- ``vehicle_config``: ``VehicleConfig``, everything one vehicle is (its model, airframe, attitude
  loop, failsafe, the air it flies in, what it reports, its initial state), validated when it is
  made, and crossing a process boundary whole as one JSON document (``python -m sim_vehicles
  --config``); ``spec``: the same under its names before (``VehicleSpec``), for a user's model
  that imports them;
- ``build``: the registry of models and ``build_vehicle``, the one function that makes a vehicle
  from its config, called by ``swarm-sitl sim``, by the vehicle process and by the fork server's
  warm-up alike;
- ``template``: a user's model to copy, runnable, with the vehicle contract in its docstring.

May import: common, plant.
"""
