"""Stand descriptions shipped with platkit: installed as the package ``platkit_data.descriptions``
(see platkit/io/shipped.py); this file only makes the folder a regular package for importlib.resources."""
