"""The built-in robots (TurtleBot3 burger and waffle, the seed's rosbot, BARN's Jackal)
and the datasheets of their parts: lidars, wheel encoders, IMUs, batteries (each number
says where it comes from)."""

from __future__ import annotations

import math
from typing import Any

from agv_mission.robots.battery import BatterySpec
from agv_mission.robots.description import (
    EncoderSpec,
    ImuSpec,
    LidarMount,
    LidarSpec,
    RobotDescription,
)

# TurtleBot3 burger and waffle (pi): ROBOTIS' e-Manual specification table, "Battery:
# Lithium polymer 11.1V 1800mAh / 19.98Wh 5C" and "Expected operating time: 2h 30m"
# (burger) / "2h" (waffle pi). The idle load is that mean power (19.98 Wh / 2.5 h = 8.0 W,
# / 2 h = 10.0 W) less what the motion model draws at full speed (0.1 W, 0.3 W); the
# charger delivers 1C (1.8 A at 11.1 V), the usual limit for charging a LiPo.
TB3_BATTERY_WH = 11.1 * 1.8


def _ticks_per_meter(ticks_per_rev: float, wheel_radius: float) -> float:
    return ticks_per_rev / (2.0 * math.pi * wheel_radius)


#: ROBOTIS LDS-01 (TurtleBot3 burger and waffle), from its datasheet: range 0.12-3.5 m,
#: 1 degree resolution, 5 Hz; precision +-10 mm at 0.12-0.499 m and +-3.5 % at 0.5-3.5 m
#: (accuracy +-15 mm and +-5 %), read as two standard deviations. Dropouts (no return from
#: dark, glossy or grazing surfaces) are our estimate.
LDS_01: dict[str, Any] = {
    "beams": 360,
    "range_min": 0.12,
    "range_max": 3.5,
    "rate": 5.0,
    "noise_std": 0.005,
    "noise_fraction": 0.0175,
    "dropout": 0.01,
}
#: Slamtec RPLIDAR A1 (the seed's rosbots): range 0.15-12 m, 1 degree, 5.5 Hz; accuracy
#: 1 % of the range up to 3 m, 2.5 % beyond 5 m (datasheet), taken as 1 % std.
RPLIDAR_A1: dict[str, Any] = {
    "beams": 360,
    "range_min": 0.15,
    "range_max": 12.0,
    "rate": 5.5,
    "noise_std": 0.005,
    "noise_fraction": 0.01,
    "dropout": 0.01,
}
#: The TurtleBot3's wheel odometry: the XL430's 4096 ticks per revolution (quantisation),
#: 0.5 % random error per read and +-0.5 % slip (rubber tyres on a hard floor), and a
#: systematic scale error of 0.2 % per wheel (tyre wear and load; Borenstein and Feng's
#: UMBmark finds wheel-diameter mismatches of this order on uncalibrated robots). Measured
#: on 2 m straight runs (six seeds): 0.7-10 cm off, median 2 cm; heading 0.1-5.6 degrees.
TB3_ENCODER: dict[str, Any] = {"noise": 0.005, "slip": 0.005, "scale_error": 0.002}
#: The OpenCR 1.0 board's InvenSense MPU-9250 (TurtleBot3 burger and waffle), from its
#: product specification (PS-MPU-9250A-01 rev 1.1): gyro rate noise spectral density
#: 0.01 deg/s/sqrt(Hz), accelerometer noise power spectral density 300 ug/sqrt(Hz);
#: published at 200 Hz (the firmware's IMU_PUBLISH_FREQUENCY, turtlebot3_core_config.h).
#: The datasheet gives no bias instability: 10 deg/h, what Allan-variance measurements of
#: consumer MEMS gyros of its class find once the start-up calibration (the OpenCR's
#: calibrationGyro) has taken the turn-on bias out. See docs/imu-and-localisation.md.
MPU_9250: dict[str, Any] = {
    "rate": 200.0,
    "gyro_noise_density": math.radians(0.01),
    "gyro_bias_instability": math.radians(10.0 / 3600.0),
    "accel_noise_density": 300e-6 * 9.80665,
}
#: InvenSense MPU-6050 (the GY-521 breakout of hobby kits; our choice for rosbots, whose
#: seed names no IMU), from its product specification (PS-MPU-6000A-00 rev 3.4): gyro
#: rate noise spectral density 0.005 deg/s/sqrt(Hz), accelerometer 400 ug/sqrt(Hz); read
#: at 100 Hz over I2C; bias instability as the MPU-9250's (not in the datasheet).
MPU_6050: dict[str, Any] = {
    "rate": 100.0,
    "gyro_noise_density": math.radians(0.005),
    "gyro_bias_instability": math.radians(10.0 / 3600.0),
    "accel_noise_density": 400e-6 * 9.80665,
}
#: The Jackal's IMU as BARN simulates it: ``jackal_description``'s ``jackal.gazebo`` runs
#: hector_gazebo_plugins' IMU at 50 Hz with rateGaussianNoise and accelGaussianNoise of
#: 0.005 (rad/s, m/s^2 per sample: densities of 0.005/sqrt(50)) and a rateDrift of
#: 0.005 rad/s, a Gauss-Markov bias with a 1 h time constant that starts at zero: its
#: spread after a minute's run, 0.005 sqrt(2 * 60 / 3600) = 0.9 mrad/s, is the bias drawn.
JACKAL_IMU: dict[str, Any] = {
    "rate": 50.0,
    "gyro_noise_density": 0.005 / math.sqrt(50.0),
    "gyro_bias_instability": 0.005 * math.sqrt(2.0 * 60.0 / 3600.0),
    "accel_noise_density": 0.005 / math.sqrt(50.0),
}


#: Hokuyo UST-10LX (the Jackal's laser in BARN: ``JACKAL_LASER_MODEL=ust10``), from its
#: datasheet: 270 degrees at 0.25 degree steps (1081 beams), 25 ms a scan (40 Hz), range
#: 0.06-10 m, accuracy +-40 mm (read as two standard deviations). Dropouts: our estimate.
UST_10LX: dict[str, Any] = {
    "beams": 1081,
    "angle_min": -math.radians(135.0),
    "angle_max": math.radians(135.0),
    "range_min": 0.06,
    "range_max": 10.0,
    "rate": 40.0,
    "noise_std": 0.02,
    "noise_fraction": 0.0,
    "dropout": 0.01,
}
#: Clearpath Jackal's outline: 508 x 430 mm (its datasheet's external dimensions), centred
#: on the robot's origin (the axle midpoint of its four wheels).
JACKAL_FOOTPRINT = [(0.254, 0.215), (-0.254, 0.215), (-0.254, -0.215), (0.254, -0.215)]


BUILTIN_ROBOTS: dict[str, RobotDescription] = {
    "burger": RobotDescription(
        name="burger",
        wheel_radius=0.033,
        wheel_separation=0.160,
        footprint_radius=0.105,
        max_linear_velocity=0.22,
        max_angular_velocity=2.84,
        max_linear_acceleration=1.0,
        max_angular_acceleration=4.0,
        mass=1.0,
        # Dynamixel XL430: 4096 ticks per revolution; errors: see TB3_ENCODER
        encoder=EncoderSpec(ticks_per_meter=_ticks_per_meter(4096, 0.033), **TB3_ENCODER),
        lidar=LidarSpec(height=0.17, **LDS_01),
        battery=BatterySpec(
            capacity=TB3_BATTERY_WH,
            voltage=11.1,
            initial_level=1.0,
            idle_power=7.9,
            charge_power=19.98,
        ),
        imu=ImuSpec(**MPU_9250),
    ),
    "waffle": RobotDescription(
        name="waffle",
        wheel_radius=0.033,
        wheel_separation=0.287,
        footprint_radius=0.22,
        max_linear_velocity=0.26,
        max_angular_velocity=1.82,
        max_linear_acceleration=1.0,
        max_angular_acceleration=3.0,
        mass=1.8,
        encoder=EncoderSpec(ticks_per_meter=_ticks_per_meter(4096, 0.033), **TB3_ENCODER),
        lidar=LidarSpec(height=0.12, **LDS_01),
        battery=BatterySpec(
            capacity=TB3_BATTERY_WH,
            voltage=11.1,
            initial_level=1.0,
            idle_power=9.7,
            charge_power=19.98,
        ),
        imu=ImuSpec(**MPU_9250),
    ),
    # The seed's home-built robot: RPLidar A1 (12 m), 190 encoder ticks per metre.
    "rosbots": RobotDescription(
        name="rosbots",
        wheel_radius=0.0325,
        wheel_separation=0.11,
        footprint_radius=0.09,
        max_linear_velocity=0.3,
        max_angular_velocity=2.0,
        max_linear_acceleration=0.8,
        max_angular_acceleration=3.0,
        mass=0.8,
        # Hobby gear motors with magnetic encoders: coarser and slipperier than a Dynamixel.
        encoder=EncoderSpec(ticks_per_meter=190.0, noise=0.02, slip=0.02, scale_error=0.005),
        lidar=LidarSpec(height=0.15, **RPLIDAR_A1),
        # The seed names no battery: a 2S LiPo of 7.4 V 2200 mAh (16.3 Wh), the common pack
        # of such kits; idle: a Raspberry Pi 3 (~2.5 W) and an RPLidar A1 (5 V, ~0.5 A);
        # charged at 1C.
        battery=BatterySpec(
            capacity=7.4 * 2.2, voltage=7.4, initial_level=1.0, idle_power=5.0, charge_power=16.28
        ),
        imu=ImuSpec(**MPU_6050),
    ),
    # Clearpath Jackal as BARN runs it (docs/robots.md gives each figure's source).
    "jackal": RobotDescription(
        name="jackal",
        wheel_radius=0.098,
        wheel_separation=0.37559,
        footprint=JACKAL_FOOTPRINT,
        max_linear_velocity=2.0,
        max_angular_velocity=4.0,
        max_linear_acceleration=2.0,
        max_angular_acceleration=8.0,
        mass=17.0,
        # 78,000 quadrature pulses per metre (datasheet); Clearpath publishes no error
        # figures: the TurtleBot3's (BARN's Jackal fuses its wheels with its IMU's gyro).
        encoder=EncoderSpec(ticks_per_meter=78000.0, **TB3_ENCODER),
        # On the front mount (0.12 m ahead of the mid mount) moved by BARN's
        # JACKAL_LASER_OFFSET "-0.065 0 0.01": 0.055 m ahead of the origin.
        lidar=LidarSpec(height=0.29, mount=LidarMount(x=0.055), **UST_10LX),
        imu=ImuSpec(**JACKAL_IMU),
    ),
}
