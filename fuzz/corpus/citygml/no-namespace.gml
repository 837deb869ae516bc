<?xml version="1.0"?>
<CityModel><a xlink:href="#a"/></CityModel>