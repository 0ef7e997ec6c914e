"""The display's hardware as the daemon sees it: the controllers as one fleet (serial, firmware
protocol), the Modbus lux sensor, and the Open Spherical Camera client with its exposure
bracket (the capture station's camera and the measuring camera). Simulated stand-ins live in
:mod:`grassd.rigs`."""
