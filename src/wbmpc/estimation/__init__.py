"""State estimation from robot sensors (section V-B): sensor models in MuJoCo, the two-stage filter."""

from wbmpc.estimation.estimator import EstimatorConfig, StateEstimator, contact_trust
from wbmpc.estimation.sensors import (
           EncoderConfig,
           ImuConfig,
           SensorConfig,
           SensorReadings,
           Sensors,
)

__all__ = ["EncoderConfig", "EstimatorConfig", "ImuConfig", "SensorConfig", "SensorReadings", "Sensors",
           "StateEstimator", "contact_trust"]
