// What the browser tests share: acting on the console's map as an operator would.

/** Clicks the map at a WGS84 position, as an operator would. */
export async function clickMap(page, lat, lon) {
  const [x, y] = await page.evaluate(([la, lo]) => {
    const { map } = window.shoalConsole;
    // EPSG:3857 from degrees, as ol/proj's fromLonLat does.
    const R = 6378137;
    const c = [(lo * Math.PI * R) / 180, R * Math.log(Math.tan(Math.PI / 4 + (la * Math.PI) / 360))];
    return map.getPixelFromCoordinate(c);
  }, [lat, lon]);
  const box = await page.locator('#map').boundingBox();
  await page.mouse.click(box.x + x, box.y + y);
}
